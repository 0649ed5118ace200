// commonlight: live-camera augmented reality with common illumination. See docs/cli.md.
#include <cstdio>
#include <string>

#include <CLI/CLI.hpp>

#include "apps/app.h"
#include "core/log.h"

int main(int argc, char** argv) {
    using namespace commonlight;
    CLI::App app{"commonlight: virtual objects lit by the real lights of a live or recorded camera stream",
                 "commonlight"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "commonlight 0.1.0");
    bool quiet = false;
    bool verbose = false;
    app.add_flag("-q,--quiet", quiet, "Only print errors");
    app.add_flag("-v,--verbose", verbose, "Print debug messages");
    app.footer("Exit codes: 0 ok, 2 usage error, 3 bad input, 4 device error. Docs: docs/cli.md");

    apps::Runner runner;
    apps::addCamerasCommand(app, runner);
    apps::addRecordCommand(app, runner);
    apps::addPlayCommand(app, runner);
    apps::addLiveCommand(app, runner);
    apps::addSimCommand(app, runner);
    apps::addCalibrateCommand(app, runner);
    apps::addCalibrateResponseCommand(app, runner);
    apps::addTrackCommand(app, runner);
    apps::addBenchCommand(app, runner);
    apps::addServeGigeCommand(app, runner);
    apps::addPlotCommand(app, runner);

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        app.exit(e);  // prints the message and the usage hint
        return apps::kExitUsage;
    }
    if (quiet) log::setLevel(log::Level::kError);
    if (verbose) log::setLevel(log::Level::kDebug);
    apps::installStopSignals();
    return runner ? runner() : apps::kExitUsage;
}
