#include "mocks/gige/gige_server.h"

#include <arv.h>

#include <algorithm>
#include <chrono>
#include <thread>
#include <cmath>
#include <cstdio>
#include <cstring>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/log.h"

namespace commonlight::mocks {

namespace {

// GenICam PFNC codes the fake camera's description offers (arv-fake-camera.xml: Mono8, Mono16,
// RGB8, BayerRG8/GR8/GB8/BG8; no Mono12).
constexpr std::uint32_t kMono8 = ARV_PIXEL_FORMAT_MONO_8;
constexpr std::uint32_t kMono16 = ARV_PIXEL_FORMAT_MONO_16;
constexpr std::uint32_t kRgb8 = ARV_PIXEL_FORMAT_RGB_8_PACKED;

constexpr const char* kSerial = "commonlight";

}  // namespace

struct GigeServer::Impl {
    ArvGvFakeCamera* gv = nullptr;
    ArvFakeCamera* fake = nullptr;  // owned by gv

    ~Impl() {
        if (gv != nullptr) g_object_unref(gv);  // stops its threads
    }

    static void fillPattern(ArvBuffer* buffer, void* data, guint32, guint32, ArvPixelFormat pixel_format) {
        auto* server = static_cast<GigeServer*>(data);
        guint32 width = 0;
        guint32 height = 0;
        arv_fake_camera_read_register(static_cast<ArvFakeCamera*>(server->fake_), ARV_FAKE_CAMERA_REGISTER_WIDTH, &width);
        arv_fake_camera_read_register(static_cast<ArvFakeCamera*>(server->fake_), ARV_FAKE_CAMERA_REGISTER_HEIGHT, &height);
        // Inside this callback the buffer reports a size of 0; it holds the payload the camera
        // computed from Width x Height x bytes per pixel.
        size_t ignored = 0;
        auto* pixels = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &ignored)));
        if (pixels == nullptr) return;
        server->fill(pixels, width, height, static_cast<std::uint32_t>(pixel_format));
    }
};

Result<void> decodeForServing(FrameFileReader& reader, const Sequence& sequence, std::size_t index,
                              PixelFormat stored, Image& out) {
    const auto path = sequence.framePath(index);
    if (stored == PixelFormat::kMjpeg) {
        Image compressed;
        CL_TRY_VOID(reader.read(path, stored, sequence.sensor.width, sequence.sensor.height, compressed));
        const cv::Mat bytes(1, static_cast<int>(compressed.sizeBytes()), CV_8UC1, compressed.data());
        const cv::Mat bgr = cv::imdecode(bytes, cv::IMREAD_COLOR);
        if (bgr.empty() || bgr.cols != sequence.sensor.width || bgr.rows != sequence.sensor.height) {
            return fail(ErrorCode::kBadInput, path.string() + ": not a decodable JPEG of " +
                                                  std::to_string(sequence.sensor.width) + "x" +
                                                  std::to_string(sequence.sensor.height));
        }
        out.reshape(PixelFormat::kRgb8, bgr.cols, bgr.rows);
        cv::Mat rgb(bgr.rows, bgr.cols, CV_8UC3, out.data(), out.stride());
        cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
        return {};
    }
    CL_TRY_VOID(reader.read(path, stored, sequence.sensor.width, sequence.sensor.height, out));
    if (out.format() == PixelFormat::kBgr8) {
        cv::Mat bgr(out.height(), out.width(), CV_8UC3, out.data(), out.stride());
        cv::cvtColor(bgr, bgr, cv::COLOR_BGR2RGB);
        out.reshape(PixelFormat::kRgb8, out.width(), out.height());
    }
    return {};
}

GigeServer::GigeServer(GigeServerOptions options, Sequence sequence)
    : options_(std::move(options)), sequence_(std::move(sequence)) {}

GigeServer::~GigeServer() {
    if (watchdog_.joinable()) {
        watchdog_.request_stop();
        watchdog_.join();
    }
    if (impl_ && impl_->fake != nullptr) {
        // Stop sending, and wait for a fill in progress (set_fill_pattern takes the fill mutex):
        // no callback reaches this object once it returns.
        arv_fake_camera_write_register(impl_->fake, ARV_FAKE_CAMERA_REGISTER_TRIGGER_MODE, 1);
        arv_fake_camera_set_fill_pattern(impl_->fake, nullptr, nullptr);
    }
    impl_.reset();  // joins the fake camera's threads
}

std::string GigeServer::deviceId() const { return std::string("Aravis-Fake-") + kSerial; }

Result<std::unique_ptr<GigeServer>> GigeServer::start(const GigeServerOptions& options) {
    CL_TRY(Sequence sequence, readSequence(options.sequence));
    if (sequence.frames.empty()) {
        return fail(ErrorCode::kBadInput, (sequence.cam_dir / "data.csv").string() + ": lists no frames");
    }
    if (options.rate_hz < 0 || !std::isfinite(options.rate_hz)) {
        return fail(ErrorCode::kUsage, "serve-gige: the rate must be a positive number");
    }
    auto server = std::unique_ptr<GigeServer>(new GigeServer(options, std::move(sequence)));
    CL_TRY_VOID(server->load());
    CL_TRY_VOID(server->serve());
    return server;
}

Result<void> GigeServer::load() {
    const std::string seq_name = sequence_.root.string();
    // The stored format: sensor.yaml's, or what the first frame holds.
    PixelFormat stored = sequence_.sensor.pixel_format;
    Image first;
    CL_TRY_VOID(reader_.read(sequence_.framePath(0), stored, sequence_.sensor.width, sequence_.sensor.height, first));
    if (stored == PixelFormat::kInvalid) stored = first.format();
    PixelFormat served = stored;
    switch (stored) {
        case PixelFormat::kGray8: pfnc_ = kMono8; break;
        case PixelFormat::kGray16: pfnc_ = kMono16; break;
        case PixelFormat::kBayerRggb8: pfnc_ = ARV_PIXEL_FORMAT_BAYER_RG_8; break;
        case PixelFormat::kBayerGrbg8: pfnc_ = ARV_PIXEL_FORMAT_BAYER_GR_8; break;
        case PixelFormat::kBayerGbrg8: pfnc_ = ARV_PIXEL_FORMAT_BAYER_GB_8; break;
        case PixelFormat::kBayerBggr8: pfnc_ = ARV_PIXEL_FORMAT_BAYER_BG_8; break;
        case PixelFormat::kRgb8:
        case PixelFormat::kBgr8:
        case PixelFormat::kMjpeg:
            pfnc_ = kRgb8;
            served = PixelFormat::kRgb8;
            break;
        default:
            return fail(ErrorCode::kUnsupported,
                        seq_name + ": cannot serve " + std::string(pixelFormatName(stored)) +
                            " frames as a GigE camera (serve-gige sends gray8, gray16, rgb8, bgr8, mjpeg and bayer_*8)");
    }
    format_.format = served;
    format_.width = sequence_.sensor.width > 0 ? sequence_.sensor.width : first.width();
    format_.height = sequence_.sensor.height > 0 ? sequence_.sensor.height : first.height();
    double rate = options_.rate_hz > 0 ? options_.rate_hz : sequence_.sensor.rate_hz;
    if (rate <= 0) rate = 30.0;
    format_.fps = rate;
    format_.frame_rates = {rate};
    frame_bytes_ = imageBytes(served, format_.width, format_.height, minStride(served, format_.width));
    // Decode up front what fits the budget, so serving at high rates does not wait on PNG/JPEG.
    sequence_.sensor.pixel_format = stored;
    cache_.resize(sequence_.frames.size());
    std::size_t cached = 0;
    for (std::size_t i = 0; i < cache_.size() && cached + frame_bytes_ <= options_.cache_bytes; ++i) {
        CL_TRY_VOID(decodeForServing(reader_, sequence_, i, stored, cache_[i]));
        if (cache_[i].format() != served || cache_[i].width() != format_.width || cache_[i].height() != format_.height) {
            return fail(ErrorCode::kBadInput, sequence_.framePath(i).string() + ": " +
                                                  std::string(pixelFormatName(cache_[i].format())) + " " +
                                                  std::to_string(cache_[i].width()) + "x" +
                                                  std::to_string(cache_[i].height()) + ", the sequence is " +
                                                  hal::describe(format_));
        }
        cached += frame_bytes_;
    }
    scratch_.reshape(served, format_.width, format_.height);
    return {};
}

Result<void> GigeServer::serve() {
    impl_ = std::make_unique<Impl>();
    impl_->gv = arv_gv_fake_camera_new(options_.address.c_str(), kSerial);
    if (impl_->gv == nullptr || !arv_gv_fake_camera_is_running(impl_->gv)) {
        return fail(ErrorCode::kDevice, "serve-gige: cannot serve a GigE camera on " + options_.address +
                                            " (not a local IPv4 address or interface, or the GVCP port 3956 is taken)");
    }
    impl_->fake = arv_gv_fake_camera_get_fake_camera(impl_->gv);
    ArvFakeCamera* fake = impl_->fake;
    fake_ = fake;
    const auto w = static_cast<guint32>(format_.width);
    const auto h = static_cast<guint32>(format_.height);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_SENSOR_WIDTH, w);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_SENSOR_HEIGHT, h);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_X_OFFSET, 0);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_Y_OFFSET, 0);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, w);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_HEIGHT, h);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT, pfnc_);
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_ACQUISITION_FRAME_PERIOD_US,
                                   static_cast<guint32>(std::lround(1e6 / format_.fps)));
    arv_fake_camera_set_fill_pattern(fake, &Impl::fillPattern, this);
    // A client that dies while streaming never sends AcquisitionStop, and the fake camera reads
    // the stream destination only when an acquisition starts: it would go on streaming to the
    // dead client's port, and the next client (whose AcquisitionStart finds the acquisition
    // already on) would get nothing. When the destination changes during an acquisition, stop
    // it for a few frame periods (the fake camera looks once per frame) and start it again, so
    // the stream goes where the new client asked.
    const auto period = std::chrono::microseconds(std::lround(1e6 / format_.fps));
    watchdog_ = std::jthread([fake, period](std::stop_token stop) {
        constexpr guint32 kStreamPort = 0x0D00;     // GigE Vision bootstrap: SCP0
        constexpr guint32 kStreamAddress = 0x0D18;  // SCDA0
        guint32 port = 0, address = 0;
        bool streaming = false;
        while (!stop.stop_requested()) {
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
            guint32 now_port = 0, now_address = 0;
            arv_fake_camera_read_register(fake, kStreamPort, &now_port);
            arv_fake_camera_read_register(fake, kStreamAddress, &now_address);
            const bool acquiring = arv_fake_camera_get_acquisition_status(fake) != 0;
            if (acquiring && streaming && (now_port != port || now_address != address)) {
                log::info("serve-gige: a new client took over a running stream; restarting it towards the new client");
                arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_ACQUISITION, 0);
                std::this_thread::sleep_for(3 * period + std::chrono::milliseconds(20));
                arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_ACQUISITION, 1);
            }
            streaming = acquiring;
            port = now_port;
            address = now_address;
        }
    });
    return {};
}

void GigeServer::fill(std::uint8_t* data, std::uint32_t width, std::uint32_t height, std::uint32_t pfnc) {
    const bool matches = pfnc == pfnc_ && width == static_cast<std::uint32_t>(format_.width) &&
                         height == static_cast<std::uint32_t>(format_.height);
    if (!matches || finished_.load(std::memory_order_relaxed)) {
        // A client asked for another format or region than the recording has: send black.
        const std::size_t bpp = pfnc == kRgb8 ? 3 : pfnc == kMono16 ? 2 : 1;
        std::memset(data, 0, static_cast<std::size_t>(width) * height * bpp);
        if (!matches && !warned_mismatch_) {
            warned_mismatch_ = true;
            char code[16];
            std::snprintf(code, sizeof(code), "0x%08x", pfnc);
            log::warning("serve-gige: a client set " + std::to_string(width) + "x" + std::to_string(height) +
                         ", pixel format " + code + "; the recording is " + hal::describe(format_) +
                         ": sending black frames");
        }
        return;
    }
    const std::uint64_t served = served_.load(std::memory_order_relaxed);
    const std::size_t n = sequence_.frames.size();
    const std::size_t index = static_cast<std::size_t>(served % n);
    const Image* frame = &cache_[index];
    if (frame->empty()) {
        if (auto decoded = decodeForServing(reader_, sequence_, index, sequence_.sensor.pixel_format, scratch_);
            !decoded || scratch_.sizeBytes() != frame_bytes_) {
            log::warning("serve-gige: frame " + std::to_string(index) + " sent black: " +
                         (decoded ? std::string("wrong size") : decoded.error().message));
            scratch_.reshape(format_.format, format_.width, format_.height);
            std::memset(scratch_.data(), 0, scratch_.sizeBytes());
        }
        frame = &scratch_;
    }
    std::memcpy(data, frame->data(), frame_bytes_);
    const std::uint64_t now_served = served + 1;
    const bool limit = options_.frames > 0 && now_served >= options_.frames;
    const bool end = !options_.loop && now_served >= n;
    if (limit || end) {
        // The fake camera sends frames only in free-running mode: switching to triggered
        // acquisition stops it after this frame.
        arv_fake_camera_write_register(static_cast<ArvFakeCamera*>(fake_), ARV_FAKE_CAMERA_REGISTER_TRIGGER_MODE, 1);
        finished_.store(true, std::memory_order_release);
    }
    served_.store(now_served, std::memory_order_release);
}

Result<void> GigeServer::servedFrame(std::size_t index, Image& out) const {
    if (index >= sequence_.frames.size()) {
        return fail(ErrorCode::kUsage, sequence_.root.string() + ": no frame " + std::to_string(index));
    }
    if (!cache_[index].empty()) {
        out.assign(cache_[index].view());
        return {};
    }
    FrameFileReader reader;
    return decodeForServing(reader, sequence_, index, sequence_.sensor.pixel_format, out);
}

}  // namespace commonlight::mocks
