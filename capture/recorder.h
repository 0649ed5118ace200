// Recorder: writes frames to a sequence (core's SequenceWriter) on its own thread.
//
// push() copies a frame into one of the recorder's own pre-allocated slots and queues it; it
// never blocks on the disk. When every slot is queued (a slow disk), the frame is counted as
// dropped by the recorder: the camera's pool is never starved by recording. The writer thread
// writes the queue in order with SequenceWriter, so a crash at any moment leaves a readable
// sequence of every frame written so far.
//
// Errors: a folder that cannot be created or written is an error of start() naming it. A write
// failure (disk full, I/O error) stops the recording: the frames already written stay valid, the
// error (file and reason) is in the summary, and later frames are counted as dropped. A frame
// the sequence cannot take (timestamp not after the previous one, a size or format change) is
// counted as rejected and recording goes on.
//
// Corrupt and incomplete frames are written, with their status in meta.csv: the data is kept.
// Frames without pixels are counted and skipped.
//
// Threads: start(), finish(), pause(), resume(), flush() from a control thread; push() from one
// producer thread at a time (the pipeline, or a camera callback: it does not block); summary()
// from any thread. The writer thread is the recorder's own.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "core/frame.h"
#include "core/result.h"
#include "core/sequence_io.h"
#include "core/sequence_writer.h"

namespace commonlight::capture {

struct RecorderOptions {
    // Frame copies between push() and the disk. Each is allocated up front when the SensorInfo
    // gives size and pixel_format; otherwise the first frames size them.
    std::size_t queue_frames = 8;
    // fdatasync every frame file before listing it (survives a power loss; slower).
    bool sync = true;
    // The writer thread waits for resume() before writing: lets a caller fill the queue first
    // (tests use it to make the queue overflow deterministically).
    bool start_paused = false;

    Result<void> validate() const;  // kUsage naming the bad field
};

struct RecorderSummary {
    std::filesystem::path root;
    std::size_t frames_written = 0;     // listed in data.csv
    std::uint64_t frames_queued = 0;    // accepted by push()
    std::uint64_t dropped = 0;          // queue full, pushed after a write error, or left when it failed
    std::uint64_t rejected = 0;         // refused by the sequence (bad timestamp, size or format change)
    std::uint64_t skipped_empty = 0;    // pushed without pixels
    std::uint64_t corrupt_written = 0;  // written with a status other than kOk
    std::optional<Error> write_error;   // the failure that stopped recording (names the file)
    std::optional<Error> first_rejection;
};

class Recorder {
public:
    // Creates root/cam0/ (SequenceWriter::create) and starts the writer thread. Errors: kUsage for
    // bad options; kIo / kNotFound naming the folder when it cannot be created or written, or when
    // it already holds a sequence.
    static Result<std::unique_ptr<Recorder>> start(const std::filesystem::path& root, SensorInfo sensor,
                                                   const RecorderOptions& options = {});
    // finish()es if needed.
    ~Recorder();
    Recorder(const Recorder&) = delete;
    Recorder& operator=(const Recorder&) = delete;

    // Producer thread. Copies `frame` (pixels and metadata) into a free recorder slot and queues
    // it; returns false when the frame was not queued (no pixels, queue full, recording stopped
    // or finished), which is counted. Never blocks on the disk; allocates only while a slot's
    // buffer is smaller than the frame (never after the first frames of a stream).
    bool push(const Frame& frame);

    // Control thread. The writer stops before its next frame / goes on.
    void pause();
    void resume();
    // Control thread. Waits until every queued frame is written (or dropped after a write
    // error). Returns at once while paused.
    void flush();

    // Control thread. Writes what is queued (even when paused), stops the writer thread, closes
    // the files and returns the summary. Later calls return the same summary.
    RecorderSummary finish();

    // Any thread: the counts so far.
    RecorderSummary summary() const;

private:
    Recorder(SequenceWriter writer, const RecorderOptions& options);
    void run();  // the writer thread
    // Writer thread, without the lock: counts the outcome of writing one frame.
    void account(const Frame& frame, Result<void> written);

    RecorderOptions options_;
    std::optional<SequenceWriter> writer_;  // used by the writer thread only, until finish()
    std::vector<Frame> slots_;              // fixed count: options_.queue_frames

    mutable std::mutex mutex_;
    std::condition_variable changed_;   // queued, resumed, finishing, or a frame done
    std::vector<std::uint32_t> free_;   // free slot indices (capacity = slot count)
    std::vector<std::uint32_t> queue_;  // ring of queued slot indices
    std::size_t queue_head_ = 0;
    std::size_t queued_ = 0;
    bool writing_ = false;
    bool paused_ = false;
    bool finishing_ = false;
    bool failed_ = false;
    RecorderSummary summary_;
    std::thread thread_;
};

}  // namespace commonlight::capture
