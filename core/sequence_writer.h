// Writes a sequence (docs/formats-sequence.md) so that a crash or kill at any moment leaves a
// readable sequence of every completed frame:
//   1. the frame file is written to a temporary name, flushed, and renamed;
//   2. only then is its row appended to data.csv (one write(2), so never half a row);
//   3. then its row in meta.csv.
// sensor.yaml is written before the first row. Not thread-safe: one writer thread.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "core/file_util.h"
#include "core/frame.h"
#include "core/frame_file.h"
#include "core/sequence_io.h"

namespace commonlight {

struct SequenceWriterOptions {
    bool sync = true;  // fdatasync each frame file before it is listed (survives power loss)
};

class SequenceWriter {
public:
    // Creates root/cam0/data/. Refuses a folder that already holds a sequence (no data is ever
    // overwritten). `sensor` may leave width/height/pixel_format unset: the first frame sets them.
    static Result<SequenceWriter> create(const std::filesystem::path& root, SensorInfo sensor,
                                         SequenceWriterOptions options = {});

    SequenceWriter(SequenceWriter&&) noexcept = default;
    SequenceWriter& operator=(SequenceWriter&&) noexcept = default;

    // Stores one frame. Errors: a timestamp not after the previous one (kBadInput), a frame
    // whose format or size differs from the sequence's (kBadInput), a failed write (kIo, the
    // sequence stays readable with the frames before).
    Result<void> write(const ImageView& image, const FrameMetadata& meta);

    const std::filesystem::path& root() const noexcept { return root_; }
    std::size_t framesWritten() const noexcept { return frames_written_; }
    const SensorInfo& sensor() const noexcept { return sensor_; }

private:
    SequenceWriter() = default;
    Result<void> writeSensor(const ImageView& first);

    std::filesystem::path root_;
    std::filesystem::path data_dir_;
    SensorInfo sensor_;
    SequenceWriterOptions options_;
    LineAppender data_csv_;
    LineAppender meta_csv_;
    FrameFileWriter encoder_;
    std::vector<std::uint8_t> encoded_;
    std::string line_;
    bool sensor_written_ = false;
    std::int64_t last_timestamp_ns_ = 0;
    std::size_t frames_written_ = 0;
};

}  // namespace commonlight
