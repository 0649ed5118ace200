#include "core/calibration_io.h"

#include <cmath>
#include <cstdint>
#include <sstream>
#include <utility>

#include "core/file_util.h"
#include "core/yaml_util.h"
#include "core/reader_guard.h"

namespace commonlight {

namespace {

enum class Format { kOpenCv, kRos };

// OpenCV's distortion vector, in order (cv::calibrateCamera's distCoeffs).
constexpr std::array<const char*, 14> kCoefficientNames = {"k1", "k2", "p1", "p2", "k3", "k4",    "k5",
                                                           "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y"};

Format detectFormat(const YAML::Node& root) {
    for (const char* key : {"camera_name", "distortion_model", "rectification_matrix", "projection_matrix"}) {
        if (root[key].IsDefined()) return Format::kRos;
    }
    return Format::kOpenCv;
}

struct Matrix {
    int rows = 0;
    int cols = 0;
    std::vector<double> data;  // row-major
    YAML::Node node;           // the matrix map
    YAML::Node key_node;       // its key, for messages about the whole matrix
    YAML::Node data_node;      // its data list, for messages about single entries
};

// A matrix entry: {rows, cols, data} (ROS) or !!opencv-matrix {rows, cols, dt, data} (OpenCV).
Result<Matrix> readMatrix(const std::string& file, const YAML::Node& root, const std::string& key, Format format) {
    Matrix m;
    CL_TRY(m.node, yaml::getMap(file, root, key));
    m.key_node = yaml::findKey(root, key);
    CL_TRY(m.rows, yaml::getInt(file, m.node, key + ".rows"));
    CL_TRY(m.cols, yaml::getInt(file, m.node, key + ".cols"));
    if (m.rows < 0 || m.cols < 0) {
        return fail(yaml::keyError(file, m.key_node, key, "rows and cols must not be negative"));
    }
    if (format == Format::kOpenCv || yaml::has(m.node, "dt")) {
        CL_TRY(const std::string dt, yaml::getString(file, m.node, key + ".dt"));
        // Single-channel element types of cv::FileStorage; "2f" and the like are point lists.
        if (dt != "d" && dt != "f" && dt != "i" && dt != "s" && dt != "w" && dt != "u" && dt != "c") {
            return fail(yaml::keyError(file, std::as_const(m.node)["dt"], key + ".dt",
                                       "element type '" + dt + "' is not a single-channel number type (d or f)"));
        }
    }
    // Checked before the lookup below: without `data` the const lookup gives a node that yaml-cpp
    // refuses to assign (it throws YAML::InvalidNode).
    CL_TRY(m.data, yaml::getDoubles(file, m.node, key + ".data"));
    m.data_node = yaml::lookup(m.node, "data");
    // rows and cols are ints from the file: their product is formed in 64 bits (two ints cannot
    // overflow it), never as int.
    const std::int64_t entries = std::int64_t{m.rows} * std::int64_t{m.cols};
    if (static_cast<std::uint64_t>(entries) != m.data.size()) {
        std::ostringstream msg;
        msg << "rows x cols = " << m.rows << " x " << m.cols << " = " << entries << " but data has "
            << m.data.size() << " numbers";
        return fail(yaml::keyError(file, m.data_node, key + ".data", msg.str()));
    }
    return m;
}

Error entryError(const std::string& file, const Matrix& m, const std::string& key, std::size_t index,
                 const std::string& problem) {
    return yaml::keyError(file, m.data_node[index], yaml::indexKey(key + ".data", index), problem);
}

Result<void> readCameraMatrix(const std::string& file, const YAML::Node& root, Format format, CameraModel& model) {
    const std::string key = "camera_matrix";
    CL_TRY(const Matrix k, readMatrix(file, root, key, format));
    if (k.rows != 3 || k.cols != 3) {
        return fail(yaml::keyError(
            file, k.key_node, key,
            "expected a 3 x 3 matrix, found " + std::to_string(k.rows) + " x " + std::to_string(k.cols)));
    }
    // [fx s cx; 0 fy cy; 0 0 1]
    if (k.data[1] != 0.0) {
        return fail(entryError(file, k, key, 1, "skew (K[0][1]) must be 0: skewed pixels are not supported"));
    }
    for (const std::size_t i : {std::size_t{3}, std::size_t{6}, std::size_t{7}}) {
        if (k.data[i] != 0.0) {
            return fail(entryError(file, k, key, i, "not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1]: must be 0"));
        }
    }
    if (k.data[8] != 1.0) {
        return fail(entryError(file, k, key, 8, "not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1]: must be 1"));
    }
    model.fx = k.data[0];
    model.cx = k.data[2];
    model.fy = k.data[4];
    model.cy = k.data[5];
    if (!(model.fx > 0.0 && model.fy > 0.0)) {
        return fail(entryError(file, k, key, model.fx > 0.0 ? 4 : 0, "focal lengths must be positive"));
    }
    if (auto valid = model.validate(); !valid) {
        return fail(yaml::keyError(file, k.key_node, key, valid.error().message));
    }
    return {};
}

Result<void> readDistortion(const std::string& file, const YAML::Node& root, Format format, CameraModel& model) {
    const std::string key = "distortion_coefficients";
    CL_TRY(const Matrix d, readMatrix(file, root, key, format));
    if (!d.data.empty() && d.rows != 1 && d.cols != 1) {
        return fail(yaml::keyError(
            file, d.key_node, key,
            "expected a vector (rows or cols 1), found " + std::to_string(d.rows) + " x " + std::to_string(d.cols)));
    }
    const std::size_t n = d.data.size();
    if (n != 0 && n != 4 && n != 5 && n != 8 && n != 12 && n != 14) {
        return fail(yaml::keyError(file, d.data_node, key + ".data",
                                   "expected 0, 4, 5, 8, 12 or 14 coefficients (OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6 "
                                   "[s1 s2 s3 s4 [tau_x tau_y]]]]), found " +
                                       std::to_string(n)));
    }
    if (format == Format::kRos) {
        CL_TRY(const std::string model_name, yaml::getString(file, root, "distortion_model"));
        const YAML::Node model_node = root["distortion_model"];
        if (model_name == "plumb_bob") {
            if (n != 0 && n != 4 && n != 5) {
                return fail(
                    yaml::keyError(file, d.data_node, key + ".data",
                                   "plumb_bob takes 5 coefficients (k1 k2 p1 p2 k3), found " + std::to_string(n)));
            }
        } else if (model_name == "rational_polynomial") {
            if (n != 8) {
                return fail(yaml::keyError(file, d.data_node, key + ".data",
                                           "rational_polynomial takes 8 coefficients, found " + std::to_string(n)));
            }
        } else {
            return fail(yaml::keyError(file, model_node, "distortion_model",
                                       "'" + model_name +
                                           "' is not supported (expected plumb_bob, or rational_polynomial with "
                                           "k4 = k5 = k6 = 0)"));
        }
    }
    for (std::size_t i = 5; i < n; ++i) {
        if (d.data[i] != 0.0) {
            std::ostringstream msg;
            msg << kCoefficientNames[i] << " = " << d.data[i]
                << ": not supported (only k1 k2 p1 p2 k3; calibrate without CALIB_RATIONAL_MODEL, "
                   "CALIB_THIN_PRISM_MODEL and CALIB_TILTED_MODEL)";
            return fail(entryError(file, d, key, i, msg.str()));
        }
    }
    Distortion& out = model.distortion;
    out = Distortion{};
    if (n >= 4) {
        out.k1 = d.data[0];
        out.k2 = d.data[1];
        out.p1 = d.data[2];
        out.p2 = d.data[3];
    }
    if (n >= 5) out.k3 = d.data[4];
    return {};
}

Result<int> readImageSize(const std::string& file, const YAML::Node& root, const char* key) {
    CL_TRY(const int value, yaml::getInt(file, root, key));
    if (value <= 0) return fail(yaml::keyError(file, root[key], key, "must be positive"));
    return value;
}

void writeMatrix(std::ostringstream& out, const char* key, int rows, int cols, const std::vector<double>& data,
                 bool opencv) {
    const char* indent = opencv ? "   " : "  ";
    out << key << ":" << (opencv ? " !!opencv-matrix" : "") << "\n";
    out << indent << "rows: " << rows << "\n" << indent << "cols: " << cols << "\n";
    if (opencv) out << indent << "dt: d\n";
    out << indent << "data: [";
    for (std::size_t i = 0; i < data.size(); ++i) {
        out << (i == 0 ? " " : ", ") << yaml::formatDouble(data[i]);
    }
    out << " ]\n";
}

std::vector<double> cameraMatrix(const CameraModel& m) { return {m.fx, 0.0, m.cx, 0.0, m.fy, m.cy, 0.0, 0.0, 1.0}; }

std::vector<double> distortionVector(const CameraModel& m) {
    const Distortion& d = m.distortion;
    return {d.k1, d.k2, d.p1, d.p2, d.k3};
}

Result<void> checkWritable(const std::filesystem::path& file, const CameraModel& model,
                           const CalibrationExtras* extras) {
    if (auto valid = model.validate(); !valid) {
        return fail(ErrorCode::kBadInput,
                    file.string() + ": refusing to write an invalid camera model: " + valid.error().message);
    }
    if (extras == nullptr) return {};
    bool finite = !extras->rms_reprojection_error_px || std::isfinite(*extras->rms_reprojection_error_px);
    for (const double e : extras->per_view_errors_px) finite = finite && std::isfinite(e);
    if (extras->std_deviations_intrinsics) {
        for (const double s : *extras->std_deviations_intrinsics) finite = finite && std::isfinite(s);
    }
    if (!finite) return fail(ErrorCode::kBadInput, file.string() + ": calibration extras must be finite");
    return {};
}

}  // namespace

Result<CameraModel> parseCalibration(const std::string& text, const std::string& name) {
    return guardReader(name, [&]() -> Result<CameraModel> {
        CL_TRY(const YAML::Node root, yaml::loadString(text, name));
        if (!root.IsMap()) {
            return fail(ErrorCode::kBadInput, yaml::where(name, root) +
                                                  ": expected a calibration (a map with image_width, image_height, "
                                                  "camera_matrix, distortion_coefficients)");
        }
        const Format format = detectFormat(root);
        CameraModel model;
        CL_TRY(model.width, readImageSize(name, root, "image_width"));
        CL_TRY(model.height, readImageSize(name, root, "image_height"));
        CL_TRY_VOID(readCameraMatrix(name, root, format, model));
        CL_TRY_VOID(readDistortion(name, root, format, model));
        if (auto valid = model.validate(); !valid) return fail(valid.error().prepend(name));
        return model;
    });
}

Result<CameraModel> readCalibration(const std::filesystem::path& file) {
    CL_TRY(const std::string text, readTextFile(file));
    return parseCalibration(text, file.string());
}

std::string formatCalibrationOpenCv(const CameraModel& model, const CalibrationExtras* extras) {
    std::ostringstream out;
    out << "%YAML:1.0\n---\n";
    if (extras != nullptr && !extras->calibration_time.empty()) {
        // Always quoted: OpenCV's reader takes an unquoted "Sat Nov 21" apart otherwise.
        const std::string quoted = yaml::quoteString(extras->calibration_time);
        out << "calibration_time: " << (quoted.front() == '"' ? quoted : "\"" + quoted + "\"") << "\n";
    }
    out << "image_width: " << model.width << "\n";
    out << "image_height: " << model.height << "\n";
    writeMatrix(out, "camera_matrix", 3, 3, cameraMatrix(model), true);
    writeMatrix(out, "distortion_coefficients", 5, 1, distortionVector(model), true);
    if (extras != nullptr) {
        if (extras->rms_reprojection_error_px) {
            out << "avg_reprojection_error: " << yaml::formatDouble(*extras->rms_reprojection_error_px) << "\n";
        }
        if (!extras->per_view_errors_px.empty()) {
            writeMatrix(out, "per_view_reprojection_errors", static_cast<int>(extras->per_view_errors_px.size()), 1,
                        extras->per_view_errors_px, true);
        }
        if (extras->std_deviations_intrinsics) {
            const auto& s = *extras->std_deviations_intrinsics;
            writeMatrix(out, "std_deviations_intrinsics", static_cast<int>(s.size()), 1, {s.begin(), s.end()}, true);
        }
    }
    return out.str();
}

std::string formatCalibrationRos(const CameraModel& model, std::string_view camera_name) {
    std::ostringstream out;
    out << "image_width: " << model.width << "\n";
    out << "image_height: " << model.height << "\n";
    out << "camera_name: " << yaml::quoteString(camera_name) << "\n";
    writeMatrix(out, "camera_matrix", 3, 3, cameraMatrix(model), false);
    out << "distortion_model: plumb_bob\n";
    writeMatrix(out, "distortion_coefficients", 1, 5, distortionVector(model), false);
    writeMatrix(out, "rectification_matrix", 3, 3, {1, 0, 0, 0, 1, 0, 0, 0, 1}, false);
    // A monocular camera: the rectified image is the undistorted one, P = [K | 0].
    writeMatrix(out, "projection_matrix", 3, 4,
                {model.fx, 0.0, model.cx, 0.0, 0.0, model.fy, model.cy, 0.0, 0.0, 0.0, 1.0, 0.0}, false);
    return out.str();
}

Result<void> writeCalibrationOpenCv(const std::filesystem::path& file, const CameraModel& model,
                                    const CalibrationExtras* extras) {
    CL_TRY_VOID(checkWritable(file, model, extras));
    return writeTextFileAtomic(file, formatCalibrationOpenCv(model, extras));
}

Result<void> writeCalibrationRos(const std::filesystem::path& file, const CameraModel& model,
                                 std::string_view camera_name) {
    CL_TRY_VOID(checkWritable(file, model, nullptr));
    return writeTextFileAtomic(file, formatCalibrationRos(model, camera_name));
}

}  // namespace commonlight
