#include "apps/bench_capture.h"

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <vector>

#include <nlohmann/json.hpp>

#ifdef COMMONLIGHT_HAVE_GSTREAMER
#include <gst/app/gstappsink.h>
#include <gst/gst.h>
#endif

#include "apps/app.h"
#include "apps/report.h"
#include "capture/capture_session.h"
#include "capture/convert.h"
#include "core/percentiles.h"
#include "core/clock.h"
#include "core/log.h"

namespace commonlight::apps {

namespace {

struct CaseResult {
    std::string name;
    std::string source;
    std::string format;
    double seconds = 0.0;
    std::uint64_t delivered = 0;
    std::uint64_t dropped_device = 0;
    std::uint64_t dropped_pipeline = 0;  // no pool slot + replaced in the mailbox
    double fps = 0.0;
    Percentiles latency_ms;
    double cpu_ms_per_frame = 0.0;
    std::string error;  // the case could not run
};

double cpuSeconds() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    return static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
           static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec) / 1e6;
}

// Our capture path: camera thread -> pool -> newest-wins mailbox -> consumer, which converts each
// frame to RGB8 as the pipeline does before tracking.
CaseResult runSession(const std::string& name, const std::string& uri, double seconds) {
    CaseResult result;
    result.name = name;
    result.source = uri;
    const hal::CameraRegistry registry = makeCameraRegistry();
    auto camera = registry.openConfigured(uri);
    if (!camera) {
        result.error = camera.error().message;
        return result;
    }
    result.format = hal::describe((*camera)->activeFormat());
    auto session = capture::CaptureSession::create(std::move(*camera), capture::CaptureOptions{});
    if (!session) {
        result.error = session.error().message;
        return result;
    }
    capture::PixelConverter converter;
    Image rgb;
    const double cpu0 = cpuSeconds();
    const std::int64_t t0 = monotonicNowNs();
    if (auto started = (*session)->start(); !started) {
        result.error = started.error().message;
        return result;
    }
    const std::int64_t end = t0 + static_cast<std::int64_t>(seconds * 1e9);
    while (monotonicNowNs() < end && !stopToken().stop_requested()) {
        auto next = (*session)->next(stopToken(), std::chrono::seconds(5));
        if (!next) {
            result.error = next.error().message;
            break;
        }
        if (!next->has_value()) break;
        FrameHandle frame = std::move(**next);
        if (frame->meta.status == FrameStatus::kOk) (void)converter.convert(frame->image.view(), PixelFormat::kRgb8, rgb);
    }
    (*session)->stop();
    result.seconds = static_cast<double>(monotonicNowNs() - t0) / 1e9;
    const double cpu = cpuSeconds() - cpu0;
    const capture::CaptureStats stats = (*session)->stats();
    result.delivered = stats.frames_delivered;
    result.dropped_device = stats.drops.device;
    result.dropped_pipeline = stats.drops.no_slot + stats.drops.mailbox;
    result.fps = result.seconds > 0 ? static_cast<double>(result.delivered) / result.seconds : 0.0;
    result.latency_ms = stats.latency_ms;
    result.cpu_ms_per_frame = result.delivered > 0 ? 1000.0 * cpu / static_cast<double>(result.delivered) : 0.0;
    return result;
}

#ifdef COMMONLIGHT_HAVE_GSTREAMER
// The same camera through GStreamer: aravissrc ! appsink, the consumer converting to RGB8 too.
// Latency: the buffer's running time (aravissrc stamps it at arrival) to the appsink pull.
CaseResult runGstreamer(const std::string& name, const std::string& address, double fps, double seconds) {
    CaseResult result;
    result.name = name;
    result.source = "aravissrc camera-name=" + address;
    if (!gst_is_initialized()) gst_init(nullptr, nullptr);
    char description[256];
    std::snprintf(description, sizeof description,
                  "aravissrc camera-name=%s do-timestamp=true ! video/x-raw,format=RGB,framerate=%d/1 ! "
                  "appsink name=sink sync=false max-buffers=2 drop=true",
                  address.c_str(), static_cast<int>(std::lround(fps)));
    GError* parse_error = nullptr;
    GstElement* pipeline = gst_parse_launch(description, &parse_error);
    if (pipeline == nullptr || parse_error != nullptr) {
        result.error = std::string("gst_parse_launch: ") + (parse_error ? parse_error->message : "failed");
        if (parse_error) g_error_free(parse_error);
        if (pipeline) gst_object_unref(pipeline);
        return result;
    }
    GstElement* sink = gst_bin_get_by_name(GST_BIN(pipeline), "sink");
    SampleReservoir latency;
    capture::PixelConverter converter;
    Image rgb;
    const double cpu0 = cpuSeconds();
    const std::int64_t t0 = monotonicNowNs();
    if (gst_element_set_state(pipeline, GST_STATE_PLAYING) == GST_STATE_CHANGE_FAILURE) {
        result.error = "the GStreamer pipeline did not start (is the camera there?)";
    } else {
        const std::int64_t end = t0 + static_cast<std::int64_t>(seconds * 1e9);
        while (monotonicNowNs() < end && !stopToken().stop_requested()) {
            GstSample* sample = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 2 * GST_SECOND);
            if (sample == nullptr) {
                result.error = "no frame from aravissrc for 2 s";
                break;
            }
            GstBuffer* buffer = gst_sample_get_buffer(sample);
            GstClock* clock = gst_element_get_clock(pipeline);
            if (clock != nullptr && GST_BUFFER_PTS_IS_VALID(buffer)) {
                const GstClockTime running = gst_clock_get_time(clock) - gst_element_get_base_time(pipeline);
                latency.add(static_cast<double>(static_cast<std::int64_t>(running) -
                                                static_cast<std::int64_t>(GST_BUFFER_PTS(buffer))) / 1e6);
            }
            if (clock != nullptr) gst_object_unref(clock);
            GstCaps* caps = gst_sample_get_caps(sample);
            const GstStructure* s = caps ? gst_caps_get_structure(caps, 0) : nullptr;
            int width = 0, height = 0;
            GstMapInfo map;
            if (s && gst_structure_get_int(s, "width", &width) && gst_structure_get_int(s, "height", &height) &&
                gst_buffer_map(buffer, &map, GST_MAP_READ)) {
                const std::string format = gst_structure_get_string(s, "format") ? gst_structure_get_string(s, "format") : "";
                const PixelFormat pf = format == "RGB" ? PixelFormat::kRgb8 : PixelFormat::kGray8;
                const ImageView view{pf, width, height, minStride(pf, width), map.data, map.size};
                (void)converter.convert(view, PixelFormat::kRgb8, rgb);
                if (result.format.empty()) result.format = format + " " + std::to_string(width) + "x" + std::to_string(height);
                gst_buffer_unmap(buffer, &map);
            }
            gst_sample_unref(sample);
            ++result.delivered;
        }
    }
    gst_element_set_state(pipeline, GST_STATE_NULL);
    result.seconds = static_cast<double>(monotonicNowNs() - t0) / 1e9;
    const double cpu = cpuSeconds() - cpu0;
    gst_object_unref(sink);
    gst_object_unref(pipeline);
    result.fps = result.seconds > 0 ? static_cast<double>(result.delivered) / result.seconds : 0.0;
    result.latency_ms = latency.percentiles();
    result.cpu_ms_per_frame = result.delivered > 0 ? 1000.0 * cpu / static_cast<double>(result.delivered) : 0.0;
    return result;
}
#endif

}  // namespace

int runBenchCapture(const BenchCaptureOptions& options) {
    std::vector<CaseResult> results;
    results.push_back(runSession("replay 30 fps", "replay:" + options.sequence + "?rate=realtime&loop=1", options.seconds));
    results.push_back(runSession("replay max rate", "replay:" + options.sequence + "?rate=max&loop=1", options.seconds));
    if (!options.gige.empty()) {
        results.push_back(runSession("aravis 30 fps", "aravis:" + options.gige + "?fps=30", options.seconds));
        results.push_back(runSession("aravis max rate", "aravis:" + options.gige + "?fps=1000", options.seconds));
#ifdef COMMONLIGHT_HAVE_GSTREAMER
        results.push_back(runGstreamer("gstreamer aravissrc 30 fps", options.gige, 30.0, options.seconds));
        results.push_back(runGstreamer("gstreamer aravissrc max rate", options.gige, 1000.0, options.seconds));
#else
        log::warning("built without GStreamer: no aravissrc comparison");
#endif
    } else {
        log::info("no --gige address: the GigE cases are left out (run serve-gige inside `unshare -n`, see docs/capture.md)");
    }

    std::printf("%-30s %-22s %8s %8s %9s %9s %9s %9s %9s\n", "case", "format", "frames", "fps", "drop dev", "drop pipe",
                "lat p50", "lat p95", "cpu/frame");
    nlohmann::json cases = nlohmann::json::array();
    bool failed = false;
    for (const CaseResult& r : results) {
        if (!r.error.empty()) {
            std::printf("%-30s error: %s\n", r.name.c_str(), r.error.c_str());
            failed = true;
        }
        std::printf("%-30s %-22s %8llu %8.2f %9llu %9llu %7.3fms %7.3fms %7.3fms\n", r.name.c_str(), r.format.c_str(),
                    static_cast<unsigned long long>(r.delivered), r.fps,
                    static_cast<unsigned long long>(r.dropped_device), static_cast<unsigned long long>(r.dropped_pipeline),
                    r.latency_ms.p50, r.latency_ms.p95, r.cpu_ms_per_frame);
        cases.push_back({{"case", r.name},
                         {"source", r.source},
                         {"format", r.format},
                         {"seconds", r.seconds},
                         {"frames", r.delivered},
                         {"fps", r.fps},
                         {"dropped", {{"device", r.dropped_device}, {"pipeline", r.dropped_pipeline}}},
                         {"latency_ms", toJson(r.latency_ms)},
                         {"cpu_ms_per_frame", r.cpu_ms_per_frame},
                         {"error", r.error}});
    }
    std::printf("latency: frame arrival to hand-over to the consumer (ours), buffer running time to appsink pull "
                "(GStreamer); cpu: process CPU time per delivered frame, the consumer converting every frame to RGB8\n");
    if (!options.json.empty()) {
        if (auto written = writeJson(options.json, nlohmann::json{{"cases", cases}}); !written) {
            return reportError(written.error());
        }
    }
    return failed ? reportError(Error{ErrorCode::kDevice, "some capture cases failed (see above)"}) : kExitOk;
}

}  // namespace commonlight::apps
