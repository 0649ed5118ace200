// The composites' error against a recording's ground truth (CompositeErrors), measured where it
// does not hold up the frame.
//
// Reading one frame's truth (a JPEG and a PNG) and comparing it with the composite takes about
// 7 ms at 640x480: a fifth of a 30 fps frame on the main thread, which must composite the next
// one. In the background the measurer copies the composite into a buffer of a small pool and
// measures on its own thread, at a lower priority (core/thread_priority.h): it keeps up on average
// and yields to tracking and compositing when the cores are busy. Frames are measured in the
// order given, so the figures are those of the foreground (the same sums in the same order). A
// frame that finds every buffer waiting is not measured and is counted (unmeasured()).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "core/image.h"
#include "core/response.h"
#include "core/result.h"
#include "core/sequence_io.h"
#include "pipeline/composite_output.h"

namespace commonlight::pipeline {

struct CompositeMeasurerOptions {
    bool background = false;  // measure on a thread of its own (false: in add(), on the caller's)
    int nice = 5;             // the thread's nice value above the caller's
    std::size_t buffers = 4;  // composites waiting at most
};

class CompositeMeasurer {
public:
    // `sequence` is borrowed and must outlive the measurer.
    CompositeMeasurer(const Sequence& sequence, const ResponseCurve& response, const CompositeMeasurerOptions& options);
    ~CompositeMeasurer();  // finish()
    CompositeMeasurer(const CompositeMeasurer&) = delete;
    CompositeMeasurer& operator=(const CompositeMeasurer&) = delete;

    // The composite (RGB8) of the frame at `timestamp_ns` against that frame's truth, when the
    // recording has it. Errors: a truth file that is unreadable or of the wrong size (kBadInput
    // naming the file); in the background, the first such error the thread met, from the next
    // add() or finish() on.
    Result<void> add(const ImageView& composite, std::int64_t timestamp_ns, double exposure_gain);
    // Waits until every composite given is measured (the thread stops; a later add() starts it
    // again). Returns the first error met.
    Result<void> finish();

    // Once finish() returned (or in the foreground, at any time on the caller's thread).
    const CompositeErrors& errors() const noexcept { return errors_; }
    std::uint64_t unmeasured() const noexcept { return unmeasured_; }

private:
    struct Job {
        Image composite;
        std::int64_t timestamp_ns = 0;
        double exposure_gain = 1.0;
    };
    Result<void> measure(const ImageView& composite, std::int64_t timestamp_ns, double exposure_gain);
    void run();

    const Sequence& sequence_;
    ResponseCurve response_;
    CompositeMeasurerOptions options_;
    CompositeErrors errors_;           // the thread's while it runs
    std::uint64_t unmeasured_ = 0;     // the caller's

    std::mutex mutex_;
    std::condition_variable wake_;     // the thread: a job, or stop
    std::deque<Job> queue_;            // guarded by mutex_
    std::vector<Image> spare_;         // buffers not in use; guarded by mutex_
    std::size_t in_use_ = 0;           // buffers queued or being measured; guarded by mutex_
    bool stopping_ = false;
    std::optional<Error> error_;       // the first error; guarded by mutex_
    std::thread thread_;
};

}  // namespace commonlight::pipeline
