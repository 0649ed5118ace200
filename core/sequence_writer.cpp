#include "core/sequence_writer.h"

#include <cstdio>

namespace commonlight {

namespace fs = std::filesystem;

Result<SequenceWriter> SequenceWriter::create(const fs::path& root, SensorInfo sensor, SequenceWriterOptions options) {
    std::error_code ec;
    const fs::path cam_dir = root / "cam0";
    if (fs::exists(cam_dir / "data.csv", ec)) {
        return fail(ErrorCode::kIo, root.string() + ": already holds a sequence (cam0/data.csv); refusing to overwrite it");
    }
    SequenceWriter writer;
    writer.root_ = root;
    writer.data_dir_ = cam_dir / "data";
    writer.sensor_ = std::move(sensor);
    writer.options_ = options;
    fs::create_directories(writer.data_dir_, ec);
    if (ec) return fail(fileError(writer.data_dir_, "cannot create folder", ec.value()));
    CL_TRY(writer.data_csv_, LineAppender::open(cam_dir / "data.csv", kDataCsvHeader));
    CL_TRY(writer.meta_csv_, LineAppender::open(cam_dir / "meta.csv", kMetaCsvHeader));
    writer.line_.reserve(256);
    return writer;
}

Result<void> SequenceWriter::writeSensor(const ImageView& first) {
    sensor_.width = first.width;
    sensor_.height = first.height;
    sensor_.pixel_format = FrameFileWriter::storedFormat(first.format);
    if (sensor_.camera) CL_TRY_VOID(sensor_.camera->checkImageSize(first.width, first.height));
    CL_TRY_VOID(writeSensorYaml(root_ / "cam0" / "sensor.yaml", sensor_));
    sensor_written_ = true;
    return {};
}

Result<void> SequenceWriter::write(const ImageView& image, const FrameMetadata& meta) {
    if (frames_written_ > 0 && meta.timestamp_ns <= last_timestamp_ns_) {
        return fail(ErrorCode::kBadInput, "frame timestamp " + std::to_string(meta.timestamp_ns) +
                                              " is not after the previous one (" +
                                              std::to_string(last_timestamp_ns_) + ")");
    }
    if (!sensor_written_) {
        CL_TRY_VOID(writeSensor(image));
    } else if (image.format != sensor_.pixel_format || image.width != sensor_.width || image.height != sensor_.height) {
        return fail(ErrorCode::kBadInput, "frame is " + std::string(pixelFormatName(image.format)) + " " +
                                              std::to_string(image.width) + "x" + std::to_string(image.height) +
                                              " but the sequence is " +
                                              std::string(pixelFormatName(sensor_.pixel_format)) + " " +
                                              std::to_string(sensor_.width) + "x" + std::to_string(sensor_.height));
    }

    // Step 1: the frame file, atomically.
    CL_TRY_VOID(encoder_.encode(image, encoded_));
    const std::string filename = std::to_string(meta.timestamp_ns) + FrameFileWriter::extension(image.format);
    CL_TRY_VOID(writeFileAtomic(data_dir_ / filename, encoded_, options_.sync));

    // Step 2: list it. If this fails the file is an orphan the readers ignore; remove it.
    line_.clear();
    line_ += std::to_string(meta.timestamp_ns);
    line_ += ',';
    line_ += filename;
    line_ += '\n';
    if (auto appended = data_csv_.append(line_); !appended) {
        std::error_code ec;
        fs::remove(data_dir_ / filename, ec);
        return appended;
    }
    last_timestamp_ns_ = meta.timestamp_ns;
    ++frames_written_;

    // Step 3: its metadata.
    char buf[160];
    const int n = std::snprintf(buf, sizeof(buf), "%lld,%llu,%.17g,%.17g,%s\n",
                                static_cast<long long>(meta.timestamp_ns), static_cast<unsigned long long>(meta.sequence),
                                meta.exposure_us, meta.analog_gain, frameStatusName(meta.status).data());
    return meta_csv_.append(std::string_view(buf, static_cast<std::size_t>(n)));
}

}  // namespace commonlight
