// commonlight cameras [--json]: every camera the backends of this build can see.
#include <cstdio>
#include <memory>

#include <nlohmann/json.hpp>

#include "apps/app.h"
#include "core/log.h"
#include "hal/hardware.h"

namespace commonlight::apps {

namespace {

struct CamerasOptions {
    bool json = false;
};

nlohmann::json toJson(const hal::StreamFormat& f) {
    return {{"format", pixelFormatName(f.format)}, {"width", f.width}, {"height", f.height}, {"fps", f.frame_rates}};
}

int runCameras(const CamerasOptions& options) {
    const hal::CameraRegistry registry = makeCameraRegistry();
    const hal::EnumerationResult found = registry.enumerate();
    if (options.json) {
        nlohmann::json out;
        out["cameras"] = nlohmann::json::array();
        for (const auto& c : found.cameras) {
            nlohmann::json formats = nlohmann::json::array();
            for (const auto& f : c.formats) formats.push_back(toJson(f));
            out["cameras"].push_back({{"uri", c.uri}, {"name", c.name}, {"backend", c.backend}, {"formats", formats}});
        }
        out["backends"] = nlohmann::json::array();
        for (const auto& b : registry.backends()) {
            out["backends"].push_back({{"scheme", b.scheme},
                                       {"description", b.description},
                                       {"options", b.options},
                                       {"enumerates", static_cast<bool>(b.enumerate)}});
        }
        out["left_out"] = nlohmann::json::array();
        for (const auto& b : hal::leftOutBackends()) out["left_out"].push_back({{"scheme", b.scheme}, {"reason", b.reason}});
        out["errors"] = nlohmann::json::array();
        for (const auto& e : found.errors) out["errors"].push_back(e.message);
        std::printf("%s\n", out.dump(2).c_str());
    } else {
        if (found.cameras.empty()) std::printf("no cameras found\n");
        for (const auto& c : found.cameras) {
            std::printf("%s  %s (%s)\n", c.uri.c_str(), c.name.c_str(), c.backend.c_str());
            for (const auto& f : c.formats) std::printf("    %s\n", hal::describe(f).c_str());
        }
        std::printf("\nbackends in this build:\n");
        for (const auto& b : registry.backends()) {
            std::printf("  %-10s %s\n", (b.scheme + ":").c_str(), b.description.c_str());
        }
        for (const auto& b : hal::leftOutBackends()) {
            std::printf("  %-10s left out: %s\n", (b.scheme + ":").c_str(), b.reason.c_str());
        }
        for (const auto& e : found.errors) log::warning(e.message);
    }
    return kExitOk;
}

}  // namespace

void addCamerasCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<CamerasOptions>();
    CLI::App* sub = app.add_subcommand("cameras", "List the cameras of every backend with their formats, sizes and rates");
    sub->add_flag("--json", options->json, "Print JSON instead of text");
    sub->callback([options, &runner] { runner = [options] { return runCameras(*options); }; });
}

}  // namespace commonlight::apps
