#include "apps/track_input.h"

#include <algorithm>
#include <system_error>

namespace commonlight::apps {
namespace {

namespace fs = std::filesystem;

bool isImageFile(const fs::path& p) {
    std::string ext = p.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return ext == ".png" || ext == ".jpg" || ext == ".jpeg";
}

}  // namespace

Result<TrackInput> openTrackInput(const fs::path& input) {
    std::error_code ec;
    if (!fs::exists(input, ec)) return fail(ErrorCode::kNotFound, input.string() + ": no such file or folder");
    TrackInput out;
    if (fs::is_regular_file(input, ec)) {
        if (!isImageFile(input)) {
            return fail(ErrorCode::kBadInput, input.string() + ": not an image (expected .png, .jpg or .jpeg)");
        }
        out.kind = TrackInput::Kind::kImage;
        out.frames.push_back({input.filename().string(), input, 0});
        return out;
    }
    // A sequence: SEQ/cam0/data.csv (or a EuRoC mav0 folder).
    if (fs::exists(input / "cam0" / "data.csv", ec) || fs::exists(input / "data.csv", ec) ||
        fs::exists(input / "mav0", ec)) {
        CL_TRY(Sequence seq, readSequence(input));
        out.kind = TrackInput::Kind::kSequence;
        for (std::size_t i = 0; i < seq.frames.size(); ++i) {
            const double exposure_us = i < seq.meta.size() && seq.meta[i] ? seq.meta[i]->exposure_us : 0.0;
            out.frames.push_back({seq.frames[i].filename, seq.framePath(i), seq.frames[i].timestamp_ns, exposure_us});
        }
        out.sensor_camera = seq.sensor.camera;
        out.scene_path = seq.scenePath();
        out.sequence = std::move(seq);
        if (out.frames.empty()) return fail(ErrorCode::kBadInput, input.string() + ": the sequence has no frames");
        return out;
    }
    out.kind = TrackInput::Kind::kFolder;
    std::vector<fs::path> files;
    for (const auto& entry : fs::directory_iterator(input, ec)) {
        if (entry.is_regular_file() && isImageFile(entry.path())) files.push_back(entry.path());
    }
    if (ec) return fail(ErrorCode::kIo, input.string() + ": cannot list the folder: " + ec.message());
    std::sort(files.begin(), files.end());
    for (const fs::path& f : files) out.frames.push_back({f.filename().string(), f, 0});
    if (out.frames.empty()) {
        return fail(ErrorCode::kBadInput, input.string() + ": no sequence (cam0/data.csv) and no .png/.jpg images");
    }
    return out;
}

Result<void> GreyFrameLoader::load(const TrackInput& input, std::size_t index, Image& grey) {
    const TrackInputFrame& frame = input.frames.at(index);
    // Sequences say how their files are stored; photos are read by their contents (JPEG as
    // MJPEG, decoded below), at any size.
    PixelFormat stored = PixelFormat::kInvalid;
    int width = 0, height = 0;
    if (input.kind == TrackInput::Kind::kSequence) {
        stored = input.sequence->sensor.pixel_format;
        width = input.sequence->sensor.width;
        height = input.sequence->sensor.height;
    }
    CL_TRY_VOID(reader_.read(frame.path, stored, width, height, raw_));
    if (raw_.format() == PixelFormat::kGray8) {
        grey.assign(raw_.view());
        return {};
    }
    if (auto ok = converter_.convert(raw_.view(), PixelFormat::kGray8, grey); !ok) {
        return fail(std::move(ok).error().prepend(frame.path.string()));
    }
    return {};
}

}  // namespace commonlight::apps
