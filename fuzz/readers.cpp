#include "fuzz/readers.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>

#include "core/calibration_io.h"
#include "core/file_util.h"
#include "core/frame_file.h"
#include "core/image.h"
#include "core/mesh_io.h"
#include "core/response.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "core/yaml_util.h"
#include "hal/aravis/aravis_support.h"
#include "hal/camera_uri.h"
#include "mocks/fault_injecting_camera.h"
#include "mocks/pacer.h"
#include "mocks/sim/sensor_params.h"
#include "mocks/sim/trajectory.h"

namespace commonlight::fuzz {

namespace fs = std::filesystem;

namespace {

// Drops the result's value: the harnesses only judge success or the error.
template <typename T>
Result<void> status(Result<T> result) {
    if (!result) return fail(std::move(result).error());
    return {};
}

Result<void> readSceneFile(const fs::path& file) {
    // The files a scene names (calibration, meshes) have their own harnesses; resolving fuzzed
    // names would read whatever the machine has at those paths.
    SceneReadOptions options;
    options.load_camera = false;
    options.load_meshes = false;
    return status(readScene(file, options));
}

Result<void> readCalibrationFile(const fs::path& file) { return status(readCalibration(file)); }
Result<void> readSensorFile(const fs::path& file) { return status(readSensorYaml(file)); }
Result<void> readDataCsvFile(const fs::path& file) { return status(readDataCsv(file)); }
Result<void> readMetaCsvFile(const fs::path& file) { return status(readMetaCsv(file)); }
Result<void> readPosesCsvFile(const fs::path& file) { return status(readPosesCsv(file)); }
Result<void> readObjFile(const fs::path& file) { return status(readObjMesh(file)); }
Result<void> readGltfFile(const fs::path& file) { return status(readGltfMesh(file, false)); }
Result<void> readGlbFile(const fs::path& file) { return status(readGltfMesh(file, true)); }
Result<void> readTrajectoryFile(const fs::path& file) { return status(mocks::sim::Trajectory::read(file)); }
Result<void> readResponseFile(const fs::path& file) { return status(ResponseCurve::readFile(file)); }

// `commonlight sim --sensor-file`: a YAML map with one key, `sensor` (docs/sim-sensor.md).
Result<void> readSimSensorFile(const fs::path& file) {
    CL_TRY(const YAML::Node root, yaml::loadFile(file));
    CL_TRY_VOID(yaml::checkKeys(file.string(), root, "", {"sensor"}));
    CL_TRY(const mocks::sim::SensorParams params,
           mocks::sim::parseSensorParams(file.string(), yaml::lookup(root, "sensor")));
    return params.validate();
}

// A frame file through the sequence reader as it reads frames of unknown layout (the result),
// then once for every other way a sequence can say how to read it (sensor.yaml's pixel_format, a
// resolution to match): those must not crash either, and their errors keep the contract too.
Result<void> readFrameFile(const fs::path& file) {
    struct Stored {
        PixelFormat format;
        int width, height;
    };
    static constexpr std::array<Stored, 7> kStored = {{{PixelFormat::kInvalid, 0, 0},
                                                       {PixelFormat::kGray16, 0, 0},
                                                       {PixelFormat::kRgba8, 0, 0},
                                                       {PixelFormat::kYuyv, 0, 0},
                                                       {PixelFormat::kNv12, 0, 0},
                                                       {PixelFormat::kMjpeg, 0, 0},
                                                       {PixelFormat::kInvalid, 8, 8}}};
    FrameFileReader reader;
    Image image;
    Result<void> first;
    for (std::size_t i = 0; i < kStored.size(); ++i) {
        const Stored& s = kStored[i];
        Result<void> result = reader.read(file, s.format, s.width, s.height, image);
        if (result && image.format() != PixelFormat::kMjpeg &&
            (image.width() <= 0 || image.height() <= 0 || image.sizeBytes() == 0)) {
            return fail(ErrorCode::kInternal, file.string() + ": read as " + std::string(pixelFormatName(s.format)) +
                                                  " gave an empty image without an error");
        }
        if (i == 0) {
            first = std::move(result);
        } else if (!result && (result.error().code != ErrorCode::kBadInput ||
                               result.error().message.find(file.string()) == std::string::npos)) {
            return result;  // a broken contract in another layout: report it
        }
    }
    return first;
}

// The file's text without one trailing newline (seed files are written by editors).
std::string uriText(const fs::path& file) {
    auto text = readTextFile(file);
    if (!text) return {};
    std::string uri = std::move(*text);
    if (!uri.empty() && uri.back() == '\n') uri.pop_back();
    return uri;
}

// A camera URI (the file holds its text) and the options every backend and wrapper reads from it
// without opening anything.
Result<void> readCameraUri(const fs::path& file) {
    CL_TRY(const hal::CameraUri uri, hal::parseCameraUri(uriText(file)));
    CL_TRY_VOID(status(hal::streamConfigFromUri(uri)));
    CL_TRY_VOID(status(uri.number("exposure_us")));
    CL_TRY_VOID(status(uri.number("gain")));
    CL_TRY_VOID(status(mocks::PlaybackOptions::fromUri(uri)));
    CL_TRY_VOID(status(mocks::FaultOptions::fromUri(uri)));
    CL_TRY_VOID(status(hal::aravis::AravisOptions::fromUri(uri)));
    return {};
}

constexpr Reader kReaders[] = {
    {"scene", ".yaml", ErrorCode::kBadInput, "scene YAML (also groundtruth/lights.yaml)", &readSceneFile},
    {"calibration", ".yaml", ErrorCode::kBadInput, "calibration YAML (OpenCV and ROS forms)", &readCalibrationFile},
    {"sensor_yaml", ".yaml", ErrorCode::kBadInput, "a sequence's cam0/sensor.yaml", &readSensorFile},
    {"data_csv", ".csv", ErrorCode::kBadInput, "a sequence's cam0/data.csv", &readDataCsvFile},
    {"meta_csv", ".csv", ErrorCode::kBadInput, "a sequence's cam0/meta.csv", &readMetaCsvFile},
    {"cam_poses_csv", ".csv", ErrorCode::kBadInput, "a sequence's groundtruth/cam_poses.csv", &readPosesCsvFile},
    {"obj", ".obj", ErrorCode::kBadInput, "Wavefront OBJ mesh", &readObjFile},
    {"gltf", ".gltf", ErrorCode::kBadInput, "glTF 2.0 mesh (JSON)", &readGltfFile},
    {"glb", ".glb", ErrorCode::kBadInput, "glTF 2.0 mesh (binary)", &readGlbFile},
    {"frame_file", ".png", ErrorCode::kBadInput, "a sequence's frame file (PNG 8/16 bit, JPEG, raw YUYV/NV12)",
     &readFrameFile},
    {"camera_uri", ".txt", ErrorCode::kUsage, "a camera URI and its options", &readCameraUri},
    {"trajectory", ".yaml", ErrorCode::kBadInput, "sim trajectory.yaml", &readTrajectoryFile},
    {"response", ".yaml", ErrorCode::kBadInput, "response file (calibrate-response)", &readResponseFile},
    {"sim_sensor", ".yaml", ErrorCode::kBadInput, "sim --sensor-file (sensor parameters)", &readSimSensorFile},
};

}  // namespace

std::span<const Reader> readers() { return kReaders; }

const Reader* findReader(std::string_view name) {
    for (const Reader& r : readers()) {
        if (r.name == name) return &r;
    }
    return nullptr;
}

std::string contractViolation(const Reader& reader, const fs::path& file, const Result<void>& result) {
    if (result) return {};
    const Error& e = result.error();
    if (e.code != reader.bad_input_code) {
        return "error code '" + std::string(errorCodeName(e.code)) + "', expected '" +
               std::string(errorCodeName(reader.bad_input_code)) + "': " + e.message;
    }
    const std::string named =
        reader.bad_input_code == ErrorCode::kUsage ? "camera URI '" + uriText(file) + "'" : file.string();
    if (e.message.find(named) == std::string::npos) return "the message does not name " + named + ": " + e.message;
    return {};
}

}  // namespace commonlight::fuzz
