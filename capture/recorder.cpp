#include "capture/recorder.h"

#include <string>
#include <utility>

#include "capture/frame_pool.h"
#include "core/log.h"

namespace commonlight::capture {

namespace {
constexpr std::size_t kMaxQueueFrames = 1024;

// A failure of the disk, not of one frame: recording cannot go on.
bool stopsRecording(const Error& error) noexcept {
    return error.code == ErrorCode::kIo || error.code == ErrorCode::kNotFound || error.code == ErrorCode::kInternal;
}
}  // namespace

Result<void> RecorderOptions::validate() const {
    if (queue_frames < 1 || queue_frames > kMaxQueueFrames) {
        return fail(ErrorCode::kUsage, "recorder queue_frames must be between 1 and " +
                                           std::to_string(kMaxQueueFrames) + ", got " + std::to_string(queue_frames));
    }
    return {};
}

Result<std::unique_ptr<Recorder>> Recorder::start(const std::filesystem::path& root, SensorInfo sensor,
                                                  const RecorderOptions& options) {
    CL_TRY_VOID(options.validate());
    const int width = sensor.width;
    const int height = sensor.height;
    const PixelFormat format = sensor.pixel_format;
    auto writer = SequenceWriter::create(root, std::move(sensor), SequenceWriterOptions{options.sync});
    if (!writer) return fail(std::move(writer.error()).prepend("cannot record to " + root.string()));
    std::unique_ptr<Recorder> recorder(new Recorder(std::move(*writer), options));
    recorder->summary_.root = root;
    // Allocate every copy now when the size is known, so push() never allocates.
    if (format != PixelFormat::kInvalid && width > 0 && height > 0) {
        const std::size_t bytes = isCompressed(format)
                                      ? mjpegSlotBytes(width, height)
                                      : imageBytes(format, width, height, minStride(format, width));
        for (Frame& slot : recorder->slots_) slot.image.reserve(bytes);
    }
    recorder->thread_ = std::thread([raw = recorder.get()] { raw->run(); });
    return recorder;
}

Recorder::Recorder(SequenceWriter writer, const RecorderOptions& options)
    : options_(options), writer_(std::move(writer)), slots_(options.queue_frames), queue_(options.queue_frames) {
    free_.reserve(slots_.size());
    for (std::size_t i = slots_.size(); i > 0; --i) free_.push_back(static_cast<std::uint32_t>(i - 1));
    paused_ = options.start_paused;
}

Recorder::~Recorder() { finish(); }

bool Recorder::push(const Frame& frame) {
    std::uint32_t index = 0;
    {
        std::lock_guard lock(mutex_);
        if (frame.image.empty()) {
            ++summary_.skipped_empty;
            return false;
        }
        if (finishing_ || failed_ || free_.empty()) {
            ++summary_.dropped;
            return false;
        }
        index = free_.back();
        free_.pop_back();
    }
    // The slot is ours alone until it is queued: copy without the lock.
    Frame& slot = slots_[index];
    slot.image.assign(frame.image.view());
    slot.meta = frame.meta;
    {
        std::lock_guard lock(mutex_);
        if (finishing_) {  // finish() began while we copied: the writer may be gone
            free_.push_back(index);
            ++summary_.dropped;
            return false;
        }
        queue_[(queue_head_ + queued_) % queue_.size()] = index;
        ++queued_;
        ++summary_.frames_queued;
    }
    changed_.notify_all();
    return true;
}

void Recorder::pause() {
    std::lock_guard lock(mutex_);
    paused_ = true;
}

void Recorder::resume() {
    {
        std::lock_guard lock(mutex_);
        paused_ = false;
    }
    changed_.notify_all();
}

void Recorder::flush() {
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return paused_ || (queued_ == 0 && !writing_); });
}

RecorderSummary Recorder::finish() {
    {
        std::lock_guard lock(mutex_);
        finishing_ = true;
        paused_ = false;
    }
    changed_.notify_all();
    if (thread_.joinable()) thread_.join();
    writer_.reset();  // closes data.csv and meta.csv
    return summary();
}

RecorderSummary Recorder::summary() const {
    std::lock_guard lock(mutex_);
    return summary_;
}

void Recorder::run() {
    std::unique_lock lock(mutex_);
    for (;;) {
        changed_.wait(lock, [&] { return (!paused_ && queued_ > 0) || (finishing_ && queued_ == 0); });
        if (queued_ == 0) break;  // finishing, and everything is written
        const std::uint32_t index = queue_[queue_head_];
        queue_head_ = (queue_head_ + 1) % queue_.size();
        --queued_;
        const Frame& frame = slots_[index];
        if (failed_) {
            ++summary_.dropped;  // queued before the write error: nowhere to go
        } else {
            writing_ = true;
            lock.unlock();
            Result<void> written = writer_->write(frame.image.view(), frame.meta);
            account(frame, std::move(written));
            lock.lock();
            writing_ = false;
        }
        free_.push_back(index);
        changed_.notify_all();  // flush() may be waiting
    }
}

void Recorder::account(const Frame& frame, Result<void> written) {
    const std::size_t frames_written = writer_->framesWritten();
    std::optional<std::string> message;
    {
        std::lock_guard lock(mutex_);
        summary_.frames_written = frames_written;
        if (written) {
            if (frame.meta.status != FrameStatus::kOk) ++summary_.corrupt_written;
            return;
        }
        Error& error = written.error();
        if (stopsRecording(error)) {
            error.prepend("recording to " + summary_.root.string() + " stopped after " +
                          std::to_string(frames_written) + " frames");
            failed_ = true;
            summary_.write_error = error;
            message = error.message;
        } else {
            ++summary_.rejected;
            if (!summary_.first_rejection) {
                error.prepend("recording to " + summary_.root.string() + ": frame " +
                              std::to_string(frame.meta.sequence) + " rejected");
                summary_.first_rejection = error;
                message = error.message;
            }
        }
    }
    if (message) log::warning(*message);
}

}  // namespace commonlight::capture
