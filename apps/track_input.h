// What `commonlight track` and `commonlight bench tracking` read: a sequence (ASL layout), a
// folder of images (jpg/png, in name order) or a single image, as 8-bit grey frames.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "capture/convert.h"
#include "core/camera_model.h"
#include "core/frame_file.h"
#include "core/image.h"
#include "core/sequence_io.h"

namespace commonlight::apps {

struct TrackInputFrame {
    std::string name;               // the CSV's "image" column: file name (relative to its folder)
    std::filesystem::path path;
    std::int64_t timestamp_ns = 0;  // the sequence's; for images, 0 (they are independent photos)
    double exposure_us = 0.0;       // meta.csv's; 0 when unknown (images, no meta.csv)
    // What the tracker needs of it: the pose is for the middle of the exposure (docs/tracking.md).
    FrameMetadata meta() const {
        FrameMetadata m;
        m.timestamp_ns = timestamp_ns;
        m.timestamp_source = TimestampSource::kRecording;
        m.exposure_us = exposure_us;
        return m;
    }
};

struct TrackInput {
    enum class Kind { kSequence, kFolder, kImage } kind = Kind::kImage;
    std::vector<TrackInputFrame> frames;
    std::optional<Sequence> sequence;  // kind kSequence
    std::optional<CameraModel> sensor_camera;           // the sequence's sensor.yaml intrinsics
    std::optional<std::filesystem::path> scene_path;    // the sequence's scene.yaml
    bool independentFrames() const { return kind != Kind::kSequence; }
};

// Errors name the path: missing, not a sequence/image folder/image, an empty folder.
Result<TrackInput> openTrackInput(const std::filesystem::path& input);

// Loads frame `index` as 8-bit grey. Keeps its buffers between calls.
class GreyFrameLoader {
public:
    Result<void> load(const TrackInput& input, std::size_t index, Image& grey);

private:
    FrameFileReader reader_;
    capture::PixelConverter converter_;
    Image raw_;
};

}  // namespace commonlight::apps
