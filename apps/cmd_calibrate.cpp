// commonlight calibrate (--images DIR | --sequence SEQ) --board SPEC --out calib.yaml: camera
// intrinsics from views of a chessboard or an AprilGrid (docs/calibration.md).
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "apps/app.h"
#include "apps/quiet.h"
#include "apps/progress.h"
#include "capture/convert.h"
#include "core/frame_file.h"
#include "core/log.h"
#include "core/sequence_io.h"
#include "tracking/calibration.h"
#include "tracking/calibration_board.h"

namespace commonlight::apps {

namespace {

namespace fs = std::filesystem;

struct CalibrateCommandOptions {
    std::string images;
    std::string sequence;
    std::string board;
    std::string out;
    bool fix_k3 = false;
    bool zero_tangential = false;
    double reject_ratio = 3.0;
    int threads = 0;  // 0: one per core, at most 8
};

// The images to calibrate from, in order, and how to read them.
struct InputImage {
    std::string name;  // for messages and the output
    fs::path path;
};
struct Inputs {
    std::vector<InputImage> images;
    PixelFormat stored = PixelFormat::kInvalid;  // a sequence's pixel_format; kInvalid: by the file's contents
    int width = 0, height = 0;                   // a sequence's resolution; 0: any
    std::string description;
};

bool isImageFile(const fs::path& path) {
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
    return ext == ".png" || ext == ".jpg" || ext == ".jpeg";
}

Result<Inputs> listImageFolder(const fs::path& dir) {
    std::error_code ec;
    if (!fs::exists(dir, ec)) return fail(ErrorCode::kNotFound, dir.string() + ": no such folder (--images)");
    if (!fs::is_directory(dir, ec)) return fail(ErrorCode::kBadInput, dir.string() + ": not a folder (--images)");
    Inputs inputs;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        if (it->is_regular_file(ec) && isImageFile(it->path())) {
            inputs.images.push_back({it->path().filename().string(), it->path()});
        }
    }
    if (ec) return fail(ErrorCode::kIo, dir.string() + ": cannot list the folder: " + ec.message());
    if (inputs.images.empty()) {
        return fail(ErrorCode::kBadInput, dir.string() + ": no .png, .jpg or .jpeg images in the folder");
    }
    std::sort(inputs.images.begin(), inputs.images.end(),
              [](const InputImage& a, const InputImage& b) { return a.name < b.name; });
    inputs.description = std::to_string(inputs.images.size()) + " images in " + dir.string();
    return inputs;
}

Result<Inputs> listSequence(const fs::path& dir) {
    CL_TRY(const Sequence sequence, readSequence(dir));
    if (sequence.frames.empty()) return fail(ErrorCode::kBadInput, dir.string() + ": the sequence has no frames");
    Inputs inputs;
    for (std::size_t i = 0; i < sequence.frames.size(); ++i) {
        inputs.images.push_back({sequence.frames[i].filename, sequence.framePath(i)});
    }
    inputs.stored = sequence.sensor.pixel_format;
    inputs.width = sequence.sensor.width;
    inputs.height = sequence.sensor.height;
    inputs.description = std::to_string(inputs.images.size()) + " frames of " + dir.string();
    return inputs;
}

std::string localTime() {
    const std::time_t now = std::time(nullptr);
    std::tm tm{};
    localtime_r(&now, &tm);
    char text[64];
    std::strftime(text, sizeof text, "%a %d %b %Y %H:%M:%S %Z", &tm);
    return text;
}

void printResult(const tracking::CalibrationResult& result, const Inputs& inputs, std::size_t found) {
    say("found the board in %zu of %zu images\n", found, inputs.images.size());
    if (!result.rejected.empty()) {
        say("rejected %zu view%s:\n", result.rejected.size(), result.rejected.size() == 1 ? "" : "s");
        for (const tracking::RejectedView& view : result.rejected) {
            say("  %s: %s\n", view.name.c_str(), view.reason.c_str());
        }
    }
    const CameraModel& m = result.model;
    const auto& s = result.std_deviations;
    const Distortion& d = m.distortion;
    say("camera %dx%d from %zu views, %zu corners: RMS reprojection error %.3f px\n", m.width, m.height,
                result.view_names.size(), result.corners, result.rms_px);
    say("  fx %.3f +- %.3f  fy %.3f +- %.3f  cx %.3f +- %.3f  cy %.3f +- %.3f (pixels)\n", m.fx, s[0], m.fy,
                s[1], m.cx, s[2], m.cy, s[3]);
    say("  k1 %.5f +- %.5f  k2 %.5f +- %.5f  p1 %.6f +- %.6f  p2 %.6f +- %.6f  k3 %.5f +- %.5f\n", d.k1, s[4],
                d.k2, s[5], d.p1, s[6], d.p2, s[7], d.k3, s[8]);
    say("  coverage: corners in %d of %d cells (%.0f%%) of a %dx%d grid\n", result.coverage.cells_hit,
                result.coverage.cols * result.coverage.rows, 100.0 * result.coverage.fraction, result.coverage.cols,
                result.coverage.rows);
}

int runCalibrate(const CalibrateCommandOptions& options) {
    // Step 1: options and inputs.
    if (options.images.empty() == options.sequence.empty()) {
        return reportError(Error{ErrorCode::kUsage, "give exactly one of --images DIR and --sequence SEQ"});
    }
    auto board = tracking::parseBoardSpec(options.board);
    if (!board) return reportError(std::move(board).error().prepend("--board"));
    const fs::path out(options.out);
    const fs::path out_dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
    if (std::error_code ec; !fs::is_directory(out_dir, ec)) {
        return reportError(
            Error{ErrorCode::kNotFound, options.out + ": the folder " + out_dir.string() + " does not exist (--out)"});
    }
    tracking::BoardDetectorOptions detector_options;
    detector_options.tag_threads = options.threads > 0
                                       ? options.threads
                                       : static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 8u));
    auto detector = tracking::BoardDetector::create(*board, detector_options);
    if (!detector) return reportError(std::move(detector).error().prepend("--board"));
    tracking::CalibrationOptions calibration_options;
    calibration_options.fix_k3 = options.fix_k3;
    calibration_options.zero_tangential = options.zero_tangential;
    calibration_options.reject_ratio = options.reject_ratio;
    if (auto valid = calibration_options.validate(); !valid) return reportError(valid.error());
    auto inputs = options.images.empty() ? listSequence(options.sequence) : listImageFolder(options.images);
    if (!inputs) return reportError(inputs.error());
    say("calibrating from %s with the board %s\n", inputs->description.c_str(), board->toString().c_str());

    // Step 2: find the board in every image. An image that cannot be read is skipped with a
    // warning (and listed among the rejected views); images of another size are an error.
    tracking::Calibrator calibrator(*board, calibration_options);
    FrameFileReader reader;
    capture::PixelConverter converter;
    Image raw;
    Image gray;
    std::size_t found = 0;
    std::size_t unreadable = 0;
    Progress progress("calibrate", inputs->images.size());
    const auto start = std::chrono::steady_clock::now();
    for (std::size_t i = 0; i < inputs->images.size(); ++i) {
        if (stopToken().stop_requested()) {
            progress.finish();
            log::warning("stopped before the calibration: nothing written");
            return 130;
        }
        const InputImage& image = inputs->images[i];
        auto loaded = reader.read(image.path, inputs->stored, inputs->width, inputs->height, raw);
        if (loaded) loaded = converter.convert(raw.view(), PixelFormat::kGray8, gray);
        if (!loaded) {
            progress.finish();
            log::warning("skipping " + image.path.string() + ": " + loaded.error().message);
            calibrator.reject(image.name, "unreadable: " + loaded.error().message);
            ++unreadable;
            progress.update(i + 1);
            continue;
        }
        auto detection = detector->detect(gray.view());
        if (!detection) {
            progress.finish();
            return reportError(std::move(detection).error().prepend(image.path.string()));
        }
        found += detection->found ? 1 : 0;
        if (auto added = calibrator.add(image.name, gray.width(), gray.height(), *detection); !added) {
            progress.finish();
            return reportError(added.error());
        }
        progress.update(i + 1);
    }
    progress.finish();
    const double detect_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    log::debug("board detection took " + std::to_string(detect_seconds) + " s");

    // Step 3: calibrate, with the rejection of views with large residuals.
    auto result = calibrator.calibrate();
    if (!result) return reportError(result.error());
    printResult(*result, *inputs, found);
    if (!result->coverage.warning.empty()) log::warning(result->coverage.warning);
    if (unreadable > 0) {
        log::warning(std::to_string(unreadable) + " unreadable image" + (unreadable == 1 ? " was" : "s were") +
                     " skipped");
    }

    // Step 4: write the calibration.
    if (auto written = tracking::writeCalibrationResult(out, *result, *board, localTime()); !written) {
        return reportError(written.error());
    }
    say("wrote %s\n", options.out.c_str());
    return kExitOk;
}

}  // namespace

void addCalibrateCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<CalibrateCommandOptions>();
    CLI::App* sub = app.add_subcommand(
        "calibrate", "Camera intrinsics and distortion from images of a calibration board (docs/calibration.md)");
    CLI::Option* images =
        sub->add_option("--images", options->images, "Folder of .png/.jpg images of the board (read in name order)");
    CLI::Option* sequence =
        sub->add_option("--sequence", options->sequence, "Sequence folder (ASL layout) of the board");
    images->excludes(sequence);
    sub->add_option("--board", options->board,
                    "chessboard:COLSxROWS:SQUARE_M (inner corners, square edge in metres) or "
                    "aprilgrid:COLSxROWS:TAG_M:SPACING_RATIO (Kalibr's tag36h11 grid)")
        ->required();
    sub->add_option("--out", options->out, "Calibration file to write (OpenCV FileStorage YAML)")->required();
    sub->add_flag("--fix-k3", options->fix_k3, "Hold k3 at 0 (lenses with little distortion, few views)");
    sub->add_flag("--zero-tangential", options->zero_tangential, "Hold p1 and p2 at 0");
    sub->add_option("--reject-ratio", options->reject_ratio,
                    "Reject views whose RMS error exceeds this many times the median (and 0.5 px)")
        ->check(CLI::Range(1.0001, 1000.0))
        ->capture_default_str();
    sub->add_option("--threads", options->threads, "AprilTag detector threads (default: one per core, at most 8)")
        ->check(CLI::Range(1, 64));
    sub->footer(
        "Exit codes: 0 ok, 2 usage (a bad --board), 3 bad input (a missing folder, fewer than 3 usable "
        "views, images of different sizes), 130 stopped");
    sub->callback([options, &runner] { runner = [options] { return runCalibrate(*options); }; });
}

}  // namespace commonlight::apps
