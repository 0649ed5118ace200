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
