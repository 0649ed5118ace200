// commonlight calibrate-response (--sequence SEQ | --images DIR) --out response.yaml: the camera's
// response from an exposure bracket (core/response_calibration.h; docs/radiometry.md).
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "apps/app.h"
#include "apps/quiet.h"
#include "capture/convert.h"
#include "core/csv.h"
#include "core/frame_file.h"
#include "core/log.h"
#include "core/response_calibration.h"
#include "core/sequence_io.h"

namespace commonlight::apps {

namespace {

namespace fs = std::filesystem;

struct CalibrateResponseOptions {
    std::string sequence;
    std::string images;
    std::string out;
    std::string method = "debevec";
    int samples = 70;
};

struct Bracket {
    std::vector<Image> images;  // RGB8
    std::vector<double> exposures_s;
    std::vector<std::string> names;
};

Result<void> addImage(Bracket& b, const fs::path& file, PixelFormat stored, double exposure_us, FrameFileReader& reader,
                      capture::PixelConverter& converter) {
    if (!(exposure_us > 0.0)) return fail(ErrorCode::kBadInput, file.string() + ": exposure must be positive");
    Image raw, rgb;
    CL_TRY_VOID(reader.read(file, stored, 0, 0, raw));
    if (auto converted = converter.convert(raw.view(), PixelFormat::kRgb8, rgb); !converted) {
        return fail(ErrorCode::kBadInput, file.string() + ": " + converted.error().message);
    }
    b.images.push_back(std::move(rgb));
    b.exposures_s.push_back(exposure_us * 1e-6);
    b.names.push_back(file.string());
    return {};
}

// A sequence's frames with meta.csv's exposures (every frame needs one).
Result<Bracket> fromSequence(const fs::path& dir) {
    CL_TRY(Sequence seq, readSequence(dir));
    if (seq.meta.empty()) {
        return fail(ErrorCode::kBadInput, (seq.cam_dir / "meta.csv").string() + ": missing; the exposures of a bracket come from it");
    }
    Bracket b;
    FrameFileReader reader;
    capture::PixelConverter converter;
    for (std::size_t i = 0; i < seq.frames.size(); ++i) {
        if (!seq.meta[i]) {
            return fail(ErrorCode::kBadInput, (seq.cam_dir / "meta.csv").string() + ": no row for frame " +
                                                  std::to_string(seq.frames[i].timestamp_ns));
        }
        CL_TRY_VOID(addImage(b, seq.framePath(i), seq.sensor.pixel_format, seq.meta[i]->exposure_us * std::max(seq.meta[i]->analog_gain, 1e-9),
                             reader, converter));
    }
    return b;
}

// DIR/exposures.csv: "filename,exposure_us" per image (relative to DIR).
Result<Bracket> fromImages(const fs::path& dir) {
    const fs::path list = dir / "exposures.csv";
    std::error_code ec;
    if (!fs::is_regular_file(list, ec)) {
        return fail(ErrorCode::kNotFound, list.string() + ": missing (one row per image: filename,exposure_us)");
    }
    CL_TRY(const auto rows, csv::read(list, 2));
    Bracket b;
    FrameFileReader reader;
    capture::PixelConverter converter;
    for (const auto& row : rows) {
        CL_TRY(const double exposure, csv::toDouble(list, row, 1, "exposure_us"));
        CL_TRY_VOID(addImage(b, dir / row.fields[0], PixelFormat::kInvalid, exposure, reader, converter));
    }
    return b;
}

int runCalibrateResponse(const CalibrateResponseOptions& options) {
    // Step 1: the bracket.
    Result<Bracket> bracket = !options.sequence.empty() ? fromSequence(options.sequence) : fromImages(options.images);
    if (!bracket) return reportError(bracket.error());
    std::vector<BracketImage> views;
    for (std::size_t i = 0; i < bracket->images.size(); ++i) {
        views.push_back({bracket->images[i].view(), bracket->exposures_s[i], bracket->names[i]});
    }
    say("bracket: %zu images\n", views.size());
    // Step 2: the response.
    const ResponseMethod method = options.method == "robertson" ? ResponseMethod::kRobertson : ResponseMethod::kDebevec;
    auto result = calibrateResponse(views, method, options.samples);
    if (!result) return reportError(result.error());
    for (const std::string& w : result->warnings) log::warning(w);
    // Step 3: write and summarise.
    if (auto written = result->curve.writeFile(options.out, options.method); !written) return reportError(written.error());
    say("response (%s) written to %s\n", options.method.c_str(), options.out.c_str());
    say("  exposures span %.1fx, %.1f%% of the values saturated\n", result->exposure_ratio, 100.0 * result->saturated_fraction);
    say("  closest model: gamma:%.2f (RMS %.1f%%); srgb RMS %.1f%%, linear RMS %.1f%% (codes 20-235, up to scale)\n",
                result->best_gamma, 100.0 * result->rms_vs_gamma, 100.0 * result->rms_vs_srgb, 100.0 * result->rms_vs_linear);
    say("  linear value of code 64 / 128 / 192: %.4f / %.4f / %.4f (green)\n", result->curve.toLinear(1, std::uint8_t{64}),
                result->curve.toLinear(1, std::uint8_t{128}), result->curve.toLinear(1, std::uint8_t{192}));
    return kExitOk;
}

}  // namespace

void addCalibrateResponseCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<CalibrateResponseOptions>();
    CLI::App* sub = app.add_subcommand("calibrate-response", "The camera's response curve from an exposure bracket (docs/radiometry.md)");
    auto* seq = sub->add_option("--sequence", options->sequence, "A sequence of a static scene; exposures from cam0/meta.csv");
    auto* images = sub->add_option("--images", options->images, "A folder of images with exposures.csv (filename,exposure_us)");
    seq->excludes(images);
    sub->add_option("--out", options->out, "The response file to write (YAML)")->required();
    sub->add_option("--method", options->method, "debevec (default) or robertson (OpenCV's CalibrateDebevec/Robertson)")
        ->check(CLI::IsMember({"debevec", "robertson"}))
        ->capture_default_str();
    sub->add_option("--samples", options->samples, "Pixels Debevec samples")->check(CLI::Range(10, 10000))->capture_default_str();
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input (the message names the file)");
    sub->callback([options, sub, &runner] {
        if (options->sequence.empty() && options->images.empty()) {
            throw CLI::ValidationError("calibrate-response", "one of --sequence or --images is required");
        }
        runner = [options] { return runCalibrateResponse(*options); };
        (void)sub;
    });
}

}  // namespace commonlight::apps
