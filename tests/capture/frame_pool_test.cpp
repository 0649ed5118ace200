#include "capture/frame_pool.h"

#include <memory>
#include <set>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace commonlight::capture {
namespace {

TEST(FramePool, LendsEverySlotThenReportsExhaustion) {
    FramePool pool(2, PixelFormat::kRgb8, 8, 4);
    EXPECT_EQ(pool.slotCount(), 2u);
    EXPECT_EQ(pool.slotBytes(), 8u * 4u * 3u);
    FrameHandle a = pool.acquire();
    FrameHandle b = pool.acquire();
    ASSERT_TRUE(a);
    ASSERT_TRUE(b);
    EXPECT_NE(a.get(), b.get());
    EXPECT_EQ(a->image.format(), PixelFormat::kRgb8);
    EXPECT_EQ(a->image.width(), 8);
    EXPECT_EQ(a->image.height(), 4);
    EXPECT_EQ(pool.inUse(), 2u);

    FrameHandle none = pool.acquire();  // never blocks: an empty handle
    EXPECT_FALSE(none);
    EXPECT_EQ(pool.acquireFailures(), 1u);

    a.reset();
    EXPECT_EQ(pool.inUse(), 1u);
    FrameHandle again = pool.acquire();
    EXPECT_TRUE(again);
    EXPECT_EQ(pool.acquireFailures(), 1u);
    EXPECT_EQ(pool.peakInUse(), 2u);
}

TEST(FramePool, HandleReturnsItsSlotOnAnotherThread) {
    FramePool pool(1, PixelFormat::kGray8, 16, 16);
    FrameHandle frame = pool.acquire();
    ASSERT_TRUE(frame);
    EXPECT_FALSE(pool.acquire());
    std::thread consumer([held = std::move(frame)]() mutable { held.reset(); });
    consumer.join();
    EXPECT_EQ(pool.inUse(), 0u);
    EXPECT_TRUE(pool.acquire());
}

TEST(FramePool, SlotsAreReusedWithoutReallocating) {
    FramePool pool(3, PixelFormat::kYuyv, 32, 8);
    std::set<const std::uint8_t*> buffers;
    for (int round = 0; round < 10; ++round) {
        std::vector<FrameHandle> held;
        for (int i = 0; i < 3; ++i) {
            held.push_back(pool.acquire());
            ASSERT_TRUE(held.back());
            buffers.insert(held.back()->image.data());
            EXPECT_EQ(held.back()->image.capacity(), pool.slotBytes());
        }
    }
    EXPECT_EQ(buffers.size(), 3u);  // the same three buffers every time
}

TEST(FramePool, AcquireResetsMetadataAndShape) {
    FramePool pool(1, PixelFormat::kRgb8, 8, 8);
    {
        FrameHandle frame = pool.acquire();
        frame->meta.sequence = 42;
        frame->meta.status = FrameStatus::kCorrupt;
        frame->image.reshape(PixelFormat::kGray8, 4, 4);  // a backend may reshape within capacity
    }
    FrameHandle frame = pool.acquire();
    EXPECT_EQ(frame->meta.sequence, 0u);
    EXPECT_EQ(frame->meta.status, FrameStatus::kOk);
    EXPECT_EQ(frame->image.format(), PixelFormat::kRgb8);
    EXPECT_EQ(frame->image.width(), 8);
}

TEST(FramePool, MjpegSlotsReserveBytes) {
    FramePool bounded(2, PixelFormat::kMjpeg, 640, 480);
    EXPECT_EQ(bounded.slotBytes(), mjpegSlotBytes(640, 480));
    EXPECT_EQ(mjpegSlotBytes(640, 480), 640u * 480u * 3u);
    EXPECT_EQ(mjpegSlotBytes(16, 16), 64u * 1024u);  // small frames still get room for headers
    FramePool explicit_bytes(1, PixelFormat::kMjpeg, 640, 480, 100'000);
    FrameHandle frame = explicit_bytes.acquire();
    ASSERT_TRUE(frame);
    EXPECT_EQ(frame->image.capacity(), 100'000u);
    EXPECT_EQ(frame->image.sizeBytes(), 0u);  // nothing received yet
    EXPECT_EQ(frame->image.format(), PixelFormat::kMjpeg);
    EXPECT_EQ(frame->image.width(), 640);
}

TEST(FramePool, ManyThreadsAcquireAndReleaseWithoutLosingSlots) {
    FramePool pool(3, PixelFormat::kGray8, 4, 4);
    constexpr int kThreads = 4;
    constexpr int kRounds = 5000;
    std::vector<std::thread> threads;
    std::vector<int> got(kThreads, 0);
    for (int t = 0; t < kThreads; ++t) {
        threads.emplace_back([&pool, &got, t] {
            for (int i = 0; i < kRounds; ++i) {
                FrameHandle frame = pool.acquire();
                if (!frame) continue;
                frame->meta.sequence = static_cast<std::uint64_t>(i);  // the slot is ours alone
                ++got[static_cast<std::size_t>(t)];
            }
        });
    }
    for (auto& thread : threads) thread.join();
    int total = 0;
    for (int g : got) total += g;
    EXPECT_EQ(static_cast<std::uint64_t>(total) + pool.acquireFailures(),
              static_cast<std::uint64_t>(kThreads * kRounds));
    EXPECT_EQ(pool.inUse(), 0u);
    EXPECT_LE(pool.peakInUse(), 3u);
}

#ifndef NDEBUG
TEST(FramePoolDeathTest, DestroyingThePoolWithALentSlotIsAContractViolation) {
    EXPECT_DEATH(
        {
            auto pool = std::make_unique<FramePool>(1, PixelFormat::kGray8, 4, 4);
            FrameHandle frame = pool->acquire();
            pool.reset();
        },
        "still holds");
}
#endif

}  // namespace
}  // namespace commonlight::capture
