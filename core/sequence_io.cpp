#include "core/sequence_io.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "core/csv.h"
#include "core/file_util.h"
#include "core/yaml_util.h"
#include "core/reader_guard.h"

namespace commonlight {

namespace fs = std::filesystem;

std::optional<fs::path> Sequence::scenePath() const {
    const fs::path scene = root / "scene.yaml";
    std::error_code ec;
    if (fs::is_regular_file(scene, ec)) return scene;
    return std::nullopt;
}

namespace {

constexpr int kMaxImageSide = 65535;

std::string formatDouble(double value) {
    char buf[32];
    std::snprintf(buf, sizeof(buf), "%.17g", value);
    return buf;
}

std::optional<FrameStatus> parseStatus(std::string_view s) {
    for (FrameStatus st : {FrameStatus::kOk, FrameStatus::kCorrupt, FrameStatus::kIncomplete}) {
        if (frameStatusName(st) == s) return st;
    }
    return std::nullopt;
}

Error badLine(const fs::path& file, int line, const std::string& problem) {
    return Error{ErrorCode::kBadInput, file.string() + ":" + std::to_string(line) + ": " + problem};
}

// Timestamps must increase strictly: a duplicate or a step back means a broken recording.
template <typename Record>
Result<void> checkIncreasing(const fs::path& file, const std::vector<csv::Row>& rows,
                             const std::vector<Record>& records) {
    for (std::size_t i = 1; i < records.size(); ++i) {
        if (records[i].timestamp_ns <= records[i - 1].timestamp_ns) {
            const char* what = records[i].timestamp_ns == records[i - 1].timestamp_ns ? "duplicate" : "decreasing";
            return fail(badLine(file, rows[i].line,
                                std::string(what) + " timestamp " + std::to_string(records[i].timestamp_ns) +
                                    " (previous row, line " + std::to_string(rows[i - 1].line) + ", has " +
                                    std::to_string(records[i - 1].timestamp_ns) + ")"));
        }
    }
    return {};
}

}  // namespace

Result<SensorInfo> readSensorYaml(const fs::path& file) {
    return guardReader(file, [&]() -> Result<SensorInfo> {
        CL_TRY(const YAML::Node root, yaml::loadFile(file));
        const std::string name = file.string();
        if (!root.IsMap()) return fail(ErrorCode::kBadInput, name + ": expected a map of sensor keys");
        SensorInfo info;
        CL_TRY(const auto resolution, yaml::getDoubles(name, root, "resolution", 2));
        // Checked before the cast: a double outside int's range (1e10) has no int value (undefined
        // behaviour). 65535 is the largest size any frame format here can hold (V4L2, PNG, OpenCV).
        for (const double v : resolution) {
            if (!(v >= 1.0 && v <= kMaxImageSide && v == std::floor(v))) {
                return fail(yaml::keyError(name, yaml::lookup(root, "resolution"), "resolution",
                                           "expected two whole numbers from 1 to " + std::to_string(kMaxImageSide) +
                                               ", found " + yaml::formatNumber(v)));
            }
        }
        info.width = static_cast<int>(resolution[0]);
        info.height = static_cast<int>(resolution[1]);
        if (root["rate_hz"]) {
            CL_TRY(info.rate_hz, yaml::getDouble(name, root, "rate_hz"));
            if (info.rate_hz < 0) return fail(yaml::keyError(name, root["rate_hz"], "rate_hz", "must not be negative"));
        }
        if (root["sensor_type"]) {
            CL_TRY(info.sensor_type, yaml::getString(name, root, "sensor_type"));
        }
        if (root["comment"] && root["comment"].IsScalar()) info.comment = root["comment"].Scalar();
        if (root["T_BS"]) {
            CL_TRY(const auto data, yaml::getDoubles(name, root["T_BS"], "T_BS.data", 16));
            for (int i = 0; i < 16; ++i) info.body_from_sensor(i / 4, i % 4) = data[i];
        }
        if (root["camera_model"]) {
            CL_TRY(const std::string model, yaml::getString(name, root, "camera_model"));
            if (model != "pinhole") {
                return fail(yaml::keyError(name, root["camera_model"], "camera_model",
                                           "'" + model + "' is not supported (only pinhole)"));
            }
        }
        if (root["intrinsics"]) {
            CL_TRY(const auto k, yaml::getDoubles(name, root, "intrinsics", 4));
            CameraModel cam;
            cam.width = info.width;
            cam.height = info.height;
            cam.fx = k[0];
            cam.fy = k[1];
            cam.cx = k[2];
            cam.cy = k[3];
            if (root["distortion_model"]) {
                CL_TRY(const std::string model, yaml::getString(name, root, "distortion_model"));
                if (model != "radial-tangential" && model != "radtan" && model != "plumb_bob" && model != "none") {
                    return fail(yaml::keyError(name, root["distortion_model"], "distortion_model",
                                               "'" + model + "' is not supported (radial-tangential)"));
                }
            }
            if (root["distortion_coefficients"]) {
                CL_TRY(const auto d, yaml::getDoubles(name, root, "distortion_coefficients"));
                if (d.size() != 4 && d.size() != 5) {
                    return fail(yaml::keyError(name, root["distortion_coefficients"], "distortion_coefficients",
                                               "expected 4 or 5 numbers (k1 k2 p1 p2 [k3]), found " +
                                                   std::to_string(d.size())));
                }
                cam.distortion = {d[0], d[1], d[2], d[3], d.size() == 5 ? d[4] : 0.0};
            }
            if (auto valid = cam.validate(); !valid) {
                return fail(yaml::keyError(name, root["intrinsics"], "intrinsics", valid.error().message));
            }
            info.camera = cam;
        }
        if (root["response"]) {
            CL_TRY(info.response, yaml::getString(name, root, "response"));
        }
        if (root["radiance_scale"]) {
            CL_TRY(const double scale, yaml::getDouble(name, root, "radiance_scale"));
            if (!(std::isfinite(scale) && scale > 0.0)) {
                return fail(yaml::keyError(name, root["radiance_scale"], "radiance_scale", "must be a positive number"));
            }
            info.radiance_scale = scale;
        }
        if (root["pixel_format"]) {
            CL_TRY(const std::string format, yaml::getString(name, root, "pixel_format"));
            const auto parsed = parsePixelFormat(format);
            if (!parsed) {
                return fail(yaml::keyError(name, root["pixel_format"], "pixel_format", "unknown pixel format '" + format + "'"));
            }
            info.pixel_format = *parsed;
        }
        return info;
    });
}

Result<void> writeSensorYaml(const fs::path& file, const SensorInfo& sensor) {
    std::ostringstream out;
    out << "# commonlight sequence: ASL/EuRoC camera sensor description (docs/formats-sequence.md)\n";
    out << "sensor_type: " << sensor.sensor_type << "\n";
    if (!sensor.comment.empty()) {
        YAML::Emitter quoted;
        quoted << YAML::DoubleQuoted << sensor.comment;
        out << "comment: " << quoted.c_str() << "\n";
    }
    out << "T_BS:\n  cols: 4\n  rows: 4\n  data: [";
    for (int i = 0; i < 16; ++i) out << (i ? ", " : "") << formatDouble(sensor.body_from_sensor(i / 4, i % 4));
    out << "]\n";
    out << "rate_hz: " << formatDouble(sensor.rate_hz) << "\n";
    out << "resolution: [" << sensor.width << ", " << sensor.height << "]\n";
    if (sensor.camera) {
        const CameraModel& c = *sensor.camera;
        out << "camera_model: pinhole\n";
        out << "intrinsics: [" << formatDouble(c.fx) << ", " << formatDouble(c.fy) << ", " << formatDouble(c.cx)
            << ", " << formatDouble(c.cy) << "]\n";
        out << "distortion_model: radial-tangential\n";
        out << "distortion_coefficients: [" << formatDouble(c.distortion.k1) << ", " << formatDouble(c.distortion.k2)
            << ", " << formatDouble(c.distortion.p1) << ", " << formatDouble(c.distortion.p2);
        if (c.distortion.k3 != 0.0) out << ", " << formatDouble(c.distortion.k3);
        out << "]\n";
    }
    out << "response: " << sensor.response << "\n";
    if (sensor.radiance_scale) out << "radiance_scale: " << formatDouble(*sensor.radiance_scale) << "\n";
    if (sensor.pixel_format != PixelFormat::kInvalid) out << "pixel_format: " << pixelFormatName(sensor.pixel_format) << "\n";
    return writeTextFileAtomic(file, out.str());
}

Result<std::vector<SequenceFrame>> readDataCsv(const fs::path& file) {
    return guardReader(file, [&]() -> Result<std::vector<SequenceFrame>> {
        CL_TRY(const auto rows, csv::read(file, 2));
        std::vector<SequenceFrame> frames;
        frames.reserve(rows.size());
        for (const auto& row : rows) {
            SequenceFrame frame;
            CL_TRY(frame.timestamp_ns, csv::toInt64(file, row, 0, "timestamp [ns]"));
            frame.filename = row.fields[1];
            const fs::path name(frame.filename);
            if (frame.filename.empty() || name.is_absolute() || frame.filename.find("..") != std::string::npos) {
                return fail(badLine(file, row.line, "filename '" + frame.filename + "' must be a path inside data/"));
            }
            frames.push_back(std::move(frame));
        }
        CL_TRY_VOID(checkIncreasing(file, rows, frames));
        return frames;
    });
}

Result<std::vector<FrameMetaRecord>> readMetaCsv(const fs::path& file) {
    return guardReader(file, [&]() -> Result<std::vector<FrameMetaRecord>> {
        CL_TRY(const auto rows, csv::read(file, 5));
        std::vector<FrameMetaRecord> records;
        records.reserve(rows.size());
        for (const auto& row : rows) {
            FrameMetaRecord r;
            CL_TRY(r.timestamp_ns, csv::toInt64(file, row, 0, "timestamp_ns"));
            CL_TRY(const std::int64_t sequence, csv::toInt64(file, row, 1, "sequence"));
            if (sequence < 0) return fail(badLine(file, row.line, "sequence must not be negative"));
            r.sequence = static_cast<std::uint64_t>(sequence);
            CL_TRY(r.exposure_us, csv::toDouble(file, row, 2, "exposure_us"));
            CL_TRY(r.analog_gain, csv::toDouble(file, row, 3, "analog_gain"));
            const auto status = parseStatus(row.fields[4]);
            if (!status) return fail(badLine(file, row.line, "status must be ok, corrupt or incomplete, found '" + row.fields[4] + "'"));
            r.status = *status;
            records.push_back(r);
        }
        CL_TRY_VOID(checkIncreasing(file, rows, records));
        return records;
    });
}

Result<std::vector<PoseRecord>> readPosesCsv(const fs::path& file) {
    return guardReader(file, [&]() -> Result<std::vector<PoseRecord>> {
        CL_TRY(const auto rows, csv::read(file, 8));
        std::vector<PoseRecord> poses;
        poses.reserve(rows.size());
        static constexpr const char* kColumns[] = {"timestamp_ns", "p_x", "p_y", "p_z", "q_w", "q_x", "q_y", "q_z"};
        for (const auto& row : rows) {
            PoseRecord pose;
            CL_TRY(pose.timestamp_ns, csv::toInt64(file, row, 0, kColumns[0]));
            double v[7];
            for (int i = 0; i < 7; ++i) {
                CL_TRY(v[i], csv::toDouble(file, row, static_cast<std::size_t>(i + 1), kColumns[i + 1]));
            }
            const Eigen::Quaterniond q(v[3], v[4], v[5], v[6]);
            if (std::abs(q.norm() - 1.0) > 1e-3) {
                return fail(badLine(file, row.line, "quaternion is not unit length (norm " + formatDouble(q.norm()) + ")"));
            }
            pose.world_from_cam = Rigid3d(q, Eigen::Vector3d(v[0], v[1], v[2]));
            poses.push_back(pose);
        }
        CL_TRY_VOID(checkIncreasing(file, rows, poses));
        return poses;
    });
}

std::string poseCsvRow(const PoseRecord& pose) {
    const auto& t = pose.world_from_cam.translation;
    const auto& q = pose.world_from_cam.rotation;
    std::string row = std::to_string(pose.timestamp_ns);
    for (double v : {t.x(), t.y(), t.z(), q.w(), q.x(), q.y(), q.z()}) {
        row += ',';
        row += formatDouble(v);
    }
    row += '\n';
    return row;
}

Result<void> writePosesCsv(const fs::path& file, const std::vector<PoseRecord>& poses) {
    std::string text = kPosesCsvHeader;
    for (const auto& p : poses) text += poseCsvRow(p);
    return writeTextFileAtomic(file, text);
}

Result<Sequence> readSequence(const fs::path& dir) {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) {
        if (!fs::exists(dir, ec)) return fail(ErrorCode::kNotFound, dir.string() + ": no such sequence folder");
        return fail(ErrorCode::kBadInput, dir.string() + ": not a sequence folder (expected a folder with cam0/data.csv)");
    }
    Sequence seq;
    if (fs::is_regular_file(dir / "data.csv", ec)) {
        seq.cam_dir = dir;
        seq.root = dir.has_parent_path() ? dir.parent_path() : fs::path(".");
        if (dir.filename().empty()) seq.root = dir.parent_path().parent_path();  // "SEQ/cam0/"
    } else if (fs::is_regular_file(dir / "cam0" / "data.csv", ec)) {
        seq.root = dir;
        seq.cam_dir = dir / "cam0";
    } else if (fs::is_regular_file(dir / "mav0" / "cam0" / "data.csv", ec)) {
        seq.root = dir / "mav0";
        seq.cam_dir = dir / "mav0" / "cam0";
    } else {
        return fail(ErrorCode::kBadInput, dir.string() + ": not a sequence folder (no cam0/data.csv)");
    }

    const fs::path sensor_file = seq.cam_dir / "sensor.yaml";
    if (!fs::exists(sensor_file, ec)) return fail(ErrorCode::kBadInput, sensor_file.string() + ": missing");
    CL_TRY(seq.sensor, readSensorYaml(sensor_file));
    CL_TRY(seq.frames, readDataCsv(seq.cam_dir / "data.csv"));

    const fs::path meta_file = seq.cam_dir / "meta.csv";
    if (fs::exists(meta_file, ec)) {
        CL_TRY(const auto records, readMetaCsv(meta_file));
        // Both files are sorted: merge by timestamp. A frame without a row keeps defaults (a
        // recorder killed between the two appends leaves exactly that).
        seq.meta.resize(seq.frames.size());
        std::size_t j = 0;
        for (std::size_t i = 0; i < seq.frames.size() && j < records.size(); ++i) {
            while (j < records.size() && records[j].timestamp_ns < seq.frames[i].timestamp_ns) ++j;
            if (j < records.size() && records[j].timestamp_ns == seq.frames[i].timestamp_ns) seq.meta[i] = records[j++];
        }
    }
    const fs::path poses_file = seq.root / "groundtruth" / "cam_poses.csv";
    if (fs::exists(poses_file, ec)) {
        CL_TRY(seq.groundtruth_poses, readPosesCsv(poses_file));
    }
    const fs::path mid_file = seq.root / "groundtruth" / kMidExposurePosesFile;
    if (fs::exists(mid_file, ec)) {
        CL_TRY(seq.groundtruth_mid_exposure_poses, readPosesCsv(mid_file));
    }
    return seq;
}

namespace {

// The row at exactly `t`, or the rows just before and after it (either may be missing).
struct Bracket {
    const PoseRecord* exact = nullptr;
    const PoseRecord* before = nullptr;
    const PoseRecord* after = nullptr;
};

void bracketIn(const std::vector<PoseRecord>& poses, std::int64_t t, Bracket& b) {
    const auto it = std::lower_bound(poses.begin(), poses.end(), t,
                                     [](const PoseRecord& p, std::int64_t v) { return p.timestamp_ns < v; });
    if (it != poses.end() && it->timestamp_ns == t) {
        b.exact = &*it;
        return;
    }
    if (it != poses.end() && (!b.after || it->timestamp_ns < b.after->timestamp_ns)) b.after = &*it;
    if (it != poses.begin() && (!b.before || std::prev(it)->timestamp_ns > b.before->timestamp_ns)) b.before = &*std::prev(it);
}

}  // namespace

std::optional<Rigid3d> groundTruthAt(const Sequence& sequence, std::int64_t instant_ns) {
    Bracket b;
    for (const auto* poses : {&sequence.groundtruth_poses, &sequence.groundtruth_mid_exposure_poses}) {
        bracketIn(*poses, instant_ns, b);
        if (b.exact) return b.exact->world_from_cam;
    }
    if (!b.before || !b.after) return std::nullopt;
    const std::int64_t gap = b.after->timestamp_ns - b.before->timestamp_ns;
    if (gap > kMaxGroundTruthGapNs) return std::nullopt;
    const double s = static_cast<double>(instant_ns - b.before->timestamp_ns) / static_cast<double>(gap);
    return interpolateSe3(b.before->world_from_cam, b.after->world_from_cam, s);
}

std::int64_t framePoseInstantNs(const Sequence& sequence, std::size_t index) {
    const std::int64_t t = sequence.frames.at(index).timestamp_ns;
    if (index < sequence.meta.size() && sequence.meta[index]) return midExposureNs(t, sequence.meta[index]->exposure_us);
    return t;
}

std::optional<Rigid3d> groundTruthOfFrame(const Sequence& sequence, std::size_t index) {
    const std::int64_t t = sequence.frames.at(index).timestamp_ns;
    if (sequence.groundtruth_mid_exposure_poses.empty()) {
        // Written before the mid-exposure file: its simulated frames show their timestamp's pose.
        Bracket b;
        bracketIn(sequence.groundtruth_poses, t, b);
        if (b.exact) return b.exact->world_from_cam;
    }
    return groundTruthAt(sequence, framePoseInstantNs(sequence, index));
}

}  // namespace commonlight
