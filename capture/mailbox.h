// Mailbox: a one-frame slot between a producer (the camera thread) and a consumer (the pipeline
// thread).
//
// Newest-wins mode (live cameras, DESIGN section 1): put() never blocks. A frame nobody took is
// replaced by the newer one; the old handle is released (its slot goes back to the pool) outside
// the lock. It counts as dropped once the consumer takes a newer frame: the user lost it. Frames
// replaced after the consumer's last take, and frames put after close(), were made after it
// stopped taking (record --frames N, Ctrl-C, the end of a stream): they are discarded, not
// dropped. The consumer always gets the newest frame, in order.
//
// Lossless mode (`--sync` playback of replay cameras only): put() blocks the producer until the
// consumer has taken the previous frame, so every frame is delivered, in order, and processing
// is deterministic. Never use it with a live device: the device would overrun its buffers while
// the camera thread waits.
//
// End of stream: close() (optionally with an error) ends the stream. The consumer still gets
// every frame put before close(), then the end: a clean end, or the error.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <optional>
#include <stop_token>

#include "core/frame.h"
#include "core/result.h"

namespace commonlight::capture {

enum class MailboxMode {
    kNewestWins,  // live: put() never blocks, unread frames are replaced and counted as dropped
    kLossless,    // --sync replay: put() waits until the consumer took the previous frame
};

// What take() returns: a frame; std::nullopt for a clean end of stream; or an Error: the one
// given to close(), kTimeout when nothing came in time, kCancelled when a stop was requested.
using MailboxTake = Result<std::optional<FrameHandle>>;

class Mailbox {
public:
    explicit Mailbox(MailboxMode mode = MailboxMode::kNewestWins) : mode_(mode) {}
    Mailbox(const Mailbox&) = delete;
    Mailbox& operator=(const Mailbox&) = delete;

    MailboxMode mode() const noexcept { return mode_; }

    // Producer thread. Newest-wins: never blocks. Lossless: blocks until the slot is empty or the
    // mailbox is closed. Returns false when the frame was not delivered: the mailbox was closed
    // (the frame is released and counted as discarded). An empty handle is ignored (returns false,
    // not counted).
    bool put(FrameHandle frame);

    // Consumer thread. Waits until a frame is there, the stream ended, `timeout` passed or a stop
    // is requested on `stop`. Frames put before close() are delivered before the end. A timeout
    // of a year or more waits without a deadline.
    MailboxTake take(std::stop_token stop, std::chrono::nanoseconds timeout);

    // Any thread; does not block beyond a short lock. Ends the stream: std::nullopt for a clean
    // end, an Error for a failure (delivered to the consumer as is). Wakes a blocked producer
    // (lossless) and the consumer. Only the first close() counts.
    void close(std::optional<Error> error = std::nullopt);
    bool closed() const;

    // Control thread, when neither producer nor consumer is active: opens the mailbox for a new
    // stream and restarts the counters at zero. A frame still inside is released (not counted).
    void reopen();

    // Frames the consumer took.
    std::uint64_t delivered() const noexcept { return delivered_.load(std::memory_order_relaxed); }
    // Frames replaced before the consumer took them, counted when it takes a newer frame.
    std::uint64_t dropped() const noexcept { return dropped_.load(std::memory_order_relaxed); }
    // Frames that did not reach the consumer but that it did not lose (yet): replaced since its
    // last take, or put after close(). delivered + dropped + discarded = every frame put.
    std::uint64_t discarded() const noexcept { return discarded_.load(std::memory_order_relaxed); }
    // True when a frame waits to be taken.
    bool pending() const;

private:
    const MailboxMode mode_;
    mutable std::mutex mutex_;
    std::condition_variable_any changed_;  // frame put, frame taken, or closed
    FrameHandle slot_;
    bool closed_ = false;
    std::optional<Error> end_error_;
    std::atomic<std::uint64_t> delivered_{0};  // written under mutex_, read without it
    std::atomic<std::uint64_t> dropped_{0};
    std::atomic<std::uint64_t> discarded_{0};
    std::uint64_t replaced_since_take_ = 0;  // under mutex_
};

}  // namespace commonlight::capture
