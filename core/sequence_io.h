// Recorded and simulated sequences in the ASL/EuRoC layout (docs/formats-sequence.md):
//
//   SEQ/cam0/data/<timestamp_ns>.png    frames (PNG 8/16 bit, or JPEG as an MJPEG camera sent it)
//   SEQ/cam0/data.csv                   "#timestamp [ns],filename"
//   SEQ/cam0/sensor.yaml                ASL keys + response, pixel_format
//   SEQ/cam0/meta.csv        optional   timestamp_ns,sequence,exposure_us,analog_gain,status
//   SEQ/groundtruth/cam_poses.csv  opt. timestamp_ns,p_x,p_y,p_z,q_w,q_x,q_y,q_z (world_from_cam)
//   SEQ/groundtruth/cam_poses_mid_exposure.csv  optional, the same at each frame's mid-exposure
//   SEQ/scene.yaml           optional
//
// A EuRoC "mav0" folder or its "mav0/cam0" folder reads as is.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/frame.h"
#include "core/pose.h"
#include "core/result.h"

namespace commonlight {

struct SensorInfo {
    int width = 0;   // pixels ("resolution")
    int height = 0;
    double rate_hz = 0.0;                // nominal frame rate, 0 when unknown
    std::optional<CameraModel> camera;   // present when "intrinsics" is given
    std::string response = "srgb";       // srgb | linear | gamma:G | <response file> (core/response.h)
    // Relative radiance (linear value of full scale / (exposure_s x analog gain)) per W/(m^2 sr):
    // the camera's radiometric calibration, when known (docs/formats-sequence.md).
    std::optional<double> radiance_scale;
    // How to interpret the frame files. kInvalid: by the file's contents (PNG gray/colour,
    // JPEG delivered as MJPEG). yuyv / nv12 files are GRAY8 PNGs holding the raw bytes
    // (2*width x height, width x 3*height/2), so every recorded format is stored losslessly.
    PixelFormat pixel_format = PixelFormat::kInvalid;
    std::string sensor_type = "camera";
    std::string comment;
    Eigen::Matrix4d body_from_sensor = Eigen::Matrix4d::Identity();  // ASL "T_BS"
};

struct SequenceFrame {
    std::int64_t timestamp_ns = 0;
    std::string filename;  // relative to cam0/data/
};

struct FrameMetaRecord {
    std::int64_t timestamp_ns = 0;
    std::uint64_t sequence = 0;
    double exposure_us = 0.0;
    double analog_gain = 0.0;
    FrameStatus status = FrameStatus::kOk;
};

struct PoseRecord {
    std::int64_t timestamp_ns = 0;
    Rigid3d world_from_cam;
};

struct Sequence {
    std::filesystem::path root;     // the folder holding cam0/ (and groundtruth/, scene.yaml)
    std::filesystem::path cam_dir;  // root/cam0
    SensorInfo sensor;
    std::vector<SequenceFrame> frames;             // timestamps strictly increasing
    std::vector<std::optional<FrameMetaRecord>> meta;  // parallel to frames; empty without meta.csv
    std::vector<PoseRecord> groundtruth_poses;     // empty without groundtruth/cam_poses.csv
    // groundtruth/cam_poses_mid_exposure.csv (same format and meaning: the pose at each row's
    // instant), the pose at the middle of each frame's exposure; empty in sequences written
    // before it (docs/formats-sequence.md).
    std::vector<PoseRecord> groundtruth_mid_exposure_poses;

    std::filesystem::path framePath(std::size_t index) const { return cam_dir / "data" / frames[index].filename; }
    // root/scene.yaml when it exists.
    std::optional<std::filesystem::path> scenePath() const;
};

// Reads a sequence from SEQ, SEQ/cam0, or a EuRoC mav0 folder. Frame files are not opened here
// (a missing or corrupt file becomes a Corrupt frame at replay). Errors name file:line (or
// file: key): a truncated row, a non-numeric timestamp, duplicate or decreasing timestamps, a
// filename that escapes the data folder, malformed sensor.yaml.
Result<Sequence> readSequence(const std::filesystem::path& dir);

Result<SensorInfo> readSensorYaml(const std::filesystem::path& file);
Result<void> writeSensorYaml(const std::filesystem::path& file, const SensorInfo& sensor);
Result<std::vector<SequenceFrame>> readDataCsv(const std::filesystem::path& file);
Result<std::vector<FrameMetaRecord>> readMetaCsv(const std::filesystem::path& file);
Result<std::vector<PoseRecord>> readPosesCsv(const std::filesystem::path& file);
Result<void> writePosesCsv(const std::filesystem::path& file, const std::vector<PoseRecord>& poses);
// One row of cam_poses.csv (with its newline), as writePosesCsv writes it: exact round trip.
std::string poseCsvRow(const PoseRecord& pose);

// The true world_from_cam at `instant_ns`: a row of cam_poses.csv or cam_poses_mid_exposure.csv
// at exactly that instant, else interpolated on SE(3) between the rows of both files just before
// and after it when they are at most kMaxGroundTruthGapNs apart; nullopt outside them.
inline constexpr std::int64_t kMaxGroundTruthGapNs = 250'000'000;
std::optional<Rigid3d> groundTruthAt(const Sequence& sequence, std::int64_t instant_ns);
// The instant frame `index` stands for: the middle of its exposure (core/frame.h midExposureNs;
// meta.csv's exposure_us, its timestamp when unknown).
std::int64_t framePoseInstantNs(const Sequence& sequence, std::size_t index);
// The true pose of frame `index`, what every comparison with the tracker uses: at the middle of
// its exposure. A sequence without cam_poses_mid_exposure.csv (written before it existed) whose
// cam_poses.csv has a row at the frame's own timestamp gives that row: its frames were rendered
// at that instant (the simulator's convention then); otherwise groundTruthAt(the middle).
std::optional<Rigid3d> groundTruthOfFrame(const Sequence& sequence, std::size_t index);

// The fixed headers, written by SequenceWriter and expected by the readers.
inline constexpr const char* kDataCsvHeader = "#timestamp [ns],filename\n";
inline constexpr const char* kMetaCsvHeader = "#timestamp_ns,sequence,exposure_us,analog_gain,status\n";
inline constexpr const char* kMidExposurePosesFile = "cam_poses_mid_exposure.csv";  // in groundtruth/
inline constexpr const char* kPosesCsvHeader = "#timestamp_ns,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n";

}  // namespace commonlight
