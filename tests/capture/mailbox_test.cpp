#include "capture/mailbox.h"

#include <chrono>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "capture/frame_pool.h"

namespace commonlight::capture {
namespace {

using namespace std::chrono_literals;
constexpr std::chrono::nanoseconds kLongWait = 30s;  // a safety net only: tests never wait for it

FrameHandle frameNumbered(FramePool& pool, std::uint64_t sequence) {
    FrameHandle frame = pool.acquire();
    EXPECT_TRUE(frame);
    if (frame) frame->meta.sequence = sequence;
    return frame;
}

std::uint64_t sequenceOf(const MailboxTake& taken) {
    EXPECT_TRUE(taken);
    EXPECT_TRUE(taken && taken->has_value());
    return taken && taken->has_value() ? (**taken)->meta.sequence : ~0ull;
}

TEST(Mailbox, NewestWinsAndCountsReplacedFramesAsDropped) {
    FramePool pool(4, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox;
    EXPECT_TRUE(mailbox.put(frameNumbered(pool, 1)));
    EXPECT_TRUE(mailbox.put(frameNumbered(pool, 2)));
    EXPECT_TRUE(mailbox.put(frameNumbered(pool, 3)));
    EXPECT_EQ(pool.inUse(), 1u);  // the replaced frames went back to the pool
    {
        MailboxTake taken = mailbox.take({}, kLongWait);
        EXPECT_EQ(sequenceOf(taken), 3u);
        EXPECT_EQ(mailbox.delivered(), 1u);
        EXPECT_EQ(mailbox.dropped(), 2u);
        EXPECT_FALSE(mailbox.pending());
    }
    EXPECT_EQ(pool.inUse(), 0u);
}

TEST(Mailbox, TakeTimesOutWhenNothingCame) {
    Mailbox mailbox;
    MailboxTake taken = mailbox.take({}, 0ms);
    ASSERT_FALSE(taken);
    EXPECT_EQ(taken.error().code, ErrorCode::kTimeout);
}

TEST(Mailbox, TakeReturnsCancelledOnStopRequest) {
    Mailbox mailbox;
    std::stop_source stop;
    MailboxTake result;
    std::thread consumer([&] { result = mailbox.take(stop.get_token(), kLongWait); });
    stop.request_stop();  // whether the consumer is already waiting or not, it must return
    consumer.join();
    ASSERT_FALSE(result);
    EXPECT_EQ(result.error().code, ErrorCode::kCancelled);
}

TEST(Mailbox, CleanCloseDeliversPendingFrameThenEnd) {
    FramePool pool(2, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox;
    mailbox.put(frameNumbered(pool, 7));
    mailbox.close();
    EXPECT_EQ(sequenceOf(mailbox.take({}, kLongWait)), 7u);
    for (int i = 0; i < 2; ++i) {  // the end repeats
        MailboxTake end = mailbox.take({}, kLongWait);
        ASSERT_TRUE(end);
        EXPECT_FALSE(end->has_value());
    }
    EXPECT_EQ(pool.inUse(), 0u);
}

TEST(Mailbox, CloseWithErrorDeliversPendingFrameThenTheError) {
    FramePool pool(2, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox;
    mailbox.put(frameNumbered(pool, 9));
    mailbox.close(Error{ErrorCode::kDevice, "v4l2:/dev/video0: device unplugged"});
    mailbox.close();  // only the first close counts
    EXPECT_EQ(sequenceOf(mailbox.take({}, kLongWait)), 9u);
    for (int i = 0; i < 2; ++i) {
        MailboxTake end = mailbox.take({}, kLongWait);
        ASSERT_FALSE(end);
        EXPECT_EQ(end.error().code, ErrorCode::kDevice);
        EXPECT_EQ(end.error().message, "v4l2:/dev/video0: device unplugged");
    }
}

// Issue 14: a frame made after the stream was closed is not a frame the user lost.
TEST(Mailbox, PutAfterCloseReleasesTheFrameAsDiscardedNotDropped) {
    FramePool pool(2, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox;
    mailbox.close();
    EXPECT_FALSE(mailbox.put(frameNumbered(pool, 1)));
    EXPECT_EQ(mailbox.dropped(), 0u);
    EXPECT_EQ(mailbox.discarded(), 1u);
    EXPECT_EQ(pool.inUse(), 0u);
    EXPECT_FALSE(mailbox.put(FrameHandle()));  // an empty handle is ignored
    EXPECT_EQ(mailbox.discarded(), 1u);
}

// Issue 14 (record --frames N): frames replaced after the consumer's last take were made after it
// stopped taking; they become drops only if it takes a newer frame.
TEST(Mailbox, FramesReplacedAfterTheLastTakeAreDroppedOnlyWhenANewerOneIsTaken) {
    FramePool pool(4, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox;
    mailbox.put(frameNumbered(pool, 1));
    mailbox.put(frameNumbered(pool, 2));  // replaces 1
    EXPECT_EQ(sequenceOf(mailbox.take({}, kLongWait)), 2u);
    EXPECT_EQ(mailbox.dropped(), 1u);
    EXPECT_EQ(mailbox.discarded(), 0u);
    // The consumer has what it wanted; the camera goes on until it is stopped.
    for (std::uint64_t i = 3; i <= 17; ++i) mailbox.put(frameNumbered(pool, i));
    mailbox.close();
    EXPECT_EQ(mailbox.dropped(), 1u);
    EXPECT_EQ(mailbox.discarded(), 14u);  // 3..16; 17 still waits in the slot
    EXPECT_EQ(mailbox.delivered() + mailbox.dropped() + mailbox.discarded() + (mailbox.pending() ? 1u : 0u), 17u);
    // Had the consumer taken 17 (delivered before the end), 3..16 were frames it lost.
    EXPECT_EQ(sequenceOf(mailbox.take({}, kLongWait)), 17u);
    EXPECT_EQ(mailbox.dropped(), 15u);
    EXPECT_EQ(mailbox.discarded(), 0u);
}

TEST(Mailbox, ReopenReleasesTheLeftoverFrameAndRestartsCounters) {
    FramePool pool(2, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox;
    mailbox.put(frameNumbered(pool, 1));
    mailbox.put(frameNumbered(pool, 2));
    mailbox.close();
    mailbox.reopen();
    EXPECT_EQ(pool.inUse(), 0u);
    EXPECT_FALSE(mailbox.closed());
    EXPECT_EQ(mailbox.dropped(), 0u);
    EXPECT_EQ(mailbox.delivered(), 0u);
    mailbox.put(frameNumbered(pool, 3));
    EXPECT_EQ(sequenceOf(mailbox.take({}, kLongWait)), 3u);
}

// One producer, one consumer, newest-wins: every frame is delivered or dropped exactly once,
// delivered frames come in order, the last frame put before close() is delivered, and every
// pool slot is back at the end.
TEST(Mailbox, ProducerAndConsumerThreadsAccountForEveryFrame) {
    constexpr std::uint64_t kFrames = 20000;
    // Producer holds 1, the mailbox 1, the consumer 1: three slots never run out.
    FramePool pool(3, PixelFormat::kGray8, 8, 8);
    Mailbox mailbox;
    std::vector<std::uint64_t> delivered;
    delivered.reserve(kFrames);
    bool clean_end = false;

    std::thread consumer([&] {
        for (;;) {
            MailboxTake taken = mailbox.take({}, kLongWait);
            if (!taken) return;
            if (!taken->has_value()) {
                clean_end = true;
                return;
            }
            delivered.push_back((**taken)->meta.sequence);
        }
    });
    std::thread producer([&] {
        for (std::uint64_t i = 1; i <= kFrames; ++i) mailbox.put(frameNumbered(pool, i));
        mailbox.close();
    });
    producer.join();
    consumer.join();

    EXPECT_TRUE(clean_end);
    EXPECT_EQ(pool.acquireFailures(), 0u);
    EXPECT_EQ(pool.inUse(), 0u);
    EXPECT_EQ(mailbox.delivered(), delivered.size());
    EXPECT_EQ(mailbox.delivered() + mailbox.dropped(), kFrames);
    EXPECT_EQ(mailbox.discarded(), 0u);  // the last frame was taken: every replaced one was lost
    ASSERT_FALSE(delivered.empty());
    for (std::size_t i = 1; i < delivered.size(); ++i) ASSERT_LT(delivered[i - 1], delivered[i]) << "at " << i;
    EXPECT_EQ(delivered.back(), kFrames);  // the newest frame before close() always arrives
}

TEST(Mailbox, LosslessModeDeliversEveryFrameInOrder) {
    constexpr std::uint64_t kFrames = 3000;
    // Producer holds the next frame while the mailbox holds one and the consumer one.
    FramePool pool(3, PixelFormat::kGray8, 8, 8);
    Mailbox mailbox(MailboxMode::kLossless);
    std::uint64_t expected = 1;
    bool in_order = true;
    std::thread consumer([&] {
        for (;;) {
            MailboxTake taken = mailbox.take({}, kLongWait);
            if (!taken || !taken->has_value()) return;
            in_order = in_order && (**taken)->meta.sequence == expected;
            ++expected;
        }
    });
    for (std::uint64_t i = 1; i <= kFrames; ++i) EXPECT_TRUE(mailbox.put(frameNumbered(pool, i)));
    mailbox.close();
    consumer.join();
    EXPECT_TRUE(in_order);
    EXPECT_EQ(expected, kFrames + 1);
    EXPECT_EQ(mailbox.delivered(), kFrames);
    EXPECT_EQ(mailbox.dropped(), 0u);
    EXPECT_EQ(pool.inUse(), 0u);
}

TEST(Mailbox, CloseWakesALosslessProducerWaitingForTheConsumer) {
    FramePool pool(3, PixelFormat::kGray8, 4, 4);
    Mailbox mailbox(MailboxMode::kLossless);
    ASSERT_TRUE(mailbox.put(frameNumbered(pool, 1)));
    bool second_delivered = true;
    std::thread producer([&] { second_delivered = mailbox.put(frameNumbered(pool, 2)); });  // blocks: slot full
    mailbox.close();
    producer.join();
    EXPECT_FALSE(second_delivered);
    EXPECT_EQ(mailbox.dropped(), 0u);  // made after the stop: not lost by the consumer
    EXPECT_EQ(mailbox.discarded(), 1u);
    EXPECT_EQ(sequenceOf(mailbox.take({}, kLongWait)), 1u);
    MailboxTake end = mailbox.take({}, kLongWait);
    ASSERT_TRUE(end);
    EXPECT_FALSE(end->has_value());
}

}  // namespace
}  // namespace commonlight::capture
