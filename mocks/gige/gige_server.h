// A GigE Vision camera that serves a recorded sequence over the real protocol (GVCP control,
// GVSP stream), built on Aravis's own fake camera (arv_gv_fake_camera_new). Any GigE client
// (commonlight's aravis: backend, arv-viewer, GStreamer's aravissrc) can watch the recording.
//
// The camera offers the sequence's format at its size, paced at its rate (AcquisitionFrameRate):
//   gray8 -> Mono8, gray16 -> Mono16, rgb8 -> RGB8, bgr8 -> RGB8 (channels swapped),
//   mjpeg -> RGB8 (each JPEG decoded once), bayer_rggb8/grbg8/gbrg8/bggr8 -> BayerRG8/GR8/GB8/BG8.
// Pixels are served bit-identical to the sequence's frames (servedFrame() gives what frame i
// looks like on the wire). Frames follow the sequence in order; a new client continues where
// the last one stopped. Without `loop` the camera stops sending after the last frame.
//
// Threads: the fake camera's own threads call fill(); the owner polls finished() / framesServed().
// Network: it listens on `address` (loopback in tests; see docs/cameras-aravis.md).
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "core/frame_file.h"
#include "core/image.h"
#include "core/result.h"
#include "core/sequence_io.h"
#include "hal/camera.h"

namespace commonlight::mocks {

struct GigeServerOptions {
    std::filesystem::path sequence;
    std::string address = "127.0.0.1";
    std::uint64_t frames = 0;  // stop sending after this many frames; 0: no limit
    bool loop = false;         // start again after the last frame
    double rate_hz = 0.0;      // 0: the sequence's rate_hz (30 when it has none)
    // Decoded frames kept in memory (the rest are decoded while serving).
    std::size_t cache_bytes = std::size_t{512} << 20;
};

class GigeServer {
public:
    // Reads the sequence, decodes its frames and starts serving. Errors: the sequence's (named
    // file), kUnsupported for a pixel format the fake camera cannot send, kDevice when the
    // address cannot be served.
    static Result<std::unique_ptr<GigeServer>> start(const GigeServerOptions& options);
    ~GigeServer();
    GigeServer(const GigeServer&) = delete;
    GigeServer& operator=(const GigeServer&) = delete;

    // The format clients see (size, our pixel format, rate).
    const hal::StreamFormat& format() const noexcept { return format_; }
    // "Aravis-Fake-<serial>": what `commonlight cameras` lists.
    std::string deviceId() const;
    const std::string& address() const noexcept { return options_.address; }
    std::size_t sequenceFrames() const noexcept { return sequence_.frames.size(); }
    std::uint64_t framesServed() const noexcept { return served_.load(std::memory_order_acquire); }
    // True once the last frame to serve went out (never with loop and no frame limit).
    bool finished() const noexcept { return finished_.load(std::memory_order_acquire); }

    // Frame `index` of the sequence as the camera sends it. Not for the serving thread.
    Result<void> servedFrame(std::size_t index, Image& out) const;

    struct Impl;

private:
    GigeServer(GigeServerOptions options, Sequence sequence);
    Result<void> load();
    Result<void> serve();
    // Called on the fake camera's thread for every frame it sends.
    void fill(std::uint8_t* data, std::uint32_t width, std::uint32_t height, std::uint32_t pfnc);
    friend struct Impl;

    const GigeServerOptions options_;
    Sequence sequence_;
    hal::StreamFormat format_;
    std::uint32_t pfnc_ = 0;
    std::size_t frame_bytes_ = 0;
    std::vector<Image> cache_;  // decoded frames, as served (empty: decode when due)
    // Serving thread only.
    FrameFileReader reader_;
    Image scratch_;
    bool warned_mismatch_ = false;
    std::atomic<std::uint64_t> served_{0};
    std::atomic<bool> finished_{false};
    std::jthread watchdog_;  // stops a stream whose client vanished
    void* fake_ = nullptr;  // ArvFakeCamera*, owned by impl_; set before serving starts
    std::unique_ptr<Impl> impl_;
};

// Decodes a sequence frame into the layout served (rgb8 for bgr8 and mjpeg). Shared by the
// server and the tests that compare what a client recorded.
Result<void> decodeForServing(FrameFileReader& reader, const Sequence& sequence, std::size_t index,
                              PixelFormat stored, Image& out);

}  // namespace commonlight::mocks
