#include "capture/mailbox.h"

#include <utility>

namespace commonlight::capture {

namespace {
constexpr std::chrono::nanoseconds kNoDeadline = std::chrono::hours(24 * 365);
}  // namespace

bool Mailbox::put(FrameHandle frame) {
    if (!frame) return false;
    FrameHandle released;  // destroyed after the lock is let go: recycling takes the pool's lock
    bool delivered = true;
    {
        std::unique_lock lock(mutex_);
        if (mode_ == MailboxMode::kLossless) {
            changed_.wait(lock, [&] { return !slot_ || closed_; });
        }
        if (closed_) {
            // The stream is over (stopped, ended or failed): the consumer takes nothing more, so
            // this frame was made after it stopped, not lost by it.
            released = std::move(frame);
            discarded_.fetch_add(1, std::memory_order_relaxed);
            delivered = false;
        } else {
            if (slot_) {
                released = std::move(slot_);  // newest wins: nobody took it
                ++replaced_since_take_;       // a drop once the consumer takes a newer frame
                discarded_.fetch_add(1, std::memory_order_relaxed);
            }
            slot_ = std::move(frame);
        }
    }
    if (delivered) changed_.notify_all();
    return delivered;
}

MailboxTake Mailbox::take(std::stop_token stop, std::chrono::nanoseconds timeout) {
    std::optional<FrameHandle> frame;
    {
        std::unique_lock lock(mutex_);
        const auto has_news = [&] { return static_cast<bool>(slot_) || closed_; };
        // steady_clock::now() + timeout must not overflow: a very long timeout has no deadline.
        const bool ready = timeout >= kNoDeadline ? changed_.wait(lock, stop, has_news)
                                                  : changed_.wait_for(lock, stop, timeout, has_news);
        if (!ready) {
            if (stop.stop_requested()) return fail(ErrorCode::kCancelled, "waiting for a frame: stop requested");
            return fail(ErrorCode::kTimeout, "no frame within " +
                                                 std::to_string(std::chrono::duration_cast<std::chrono::milliseconds>(
                                                                    timeout).count()) + " ms");
        }
        if (!slot_) {  // closed and drained
            if (end_error_) return fail(*end_error_);
            return std::optional<FrameHandle>();
        }
        frame.emplace(std::move(slot_));
        delivered_.fetch_add(1, std::memory_order_relaxed);
        // The frames replaced since the last take came before this one: the consumer lost them.
        dropped_.fetch_add(replaced_since_take_, std::memory_order_relaxed);
        discarded_.fetch_sub(replaced_since_take_, std::memory_order_relaxed);
        replaced_since_take_ = 0;
    }
    changed_.notify_all();  // a lossless producer may put the next frame
    return frame;
}

void Mailbox::close(std::optional<Error> error) {
    {
        std::lock_guard lock(mutex_);
        if (closed_) return;
        closed_ = true;
        end_error_ = std::move(error);
    }
    changed_.notify_all();
}

bool Mailbox::closed() const {
    std::lock_guard lock(mutex_);
    return closed_;
}

void Mailbox::reopen() {
    FrameHandle released;
    {
        std::lock_guard lock(mutex_);
        released = std::move(slot_);
        closed_ = false;
        delivered_.store(0, std::memory_order_relaxed);
        dropped_.store(0, std::memory_order_relaxed);
        discarded_.store(0, std::memory_order_relaxed);
        replaced_since_take_ = 0;
        end_error_.reset();
    }
    changed_.notify_all();
}

bool Mailbox::pending() const {
    std::lock_guard lock(mutex_);
    return static_cast<bool>(slot_);
}

}  // namespace commonlight::capture
