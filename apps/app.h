// Shared pieces of the commonlight command line: subcommand registration, error reporting,
// the camera registry with every backend of this build, and Ctrl-C handling.
#pragma once

#include <functional>
#include <stop_token>
#include <string>

#include <CLI/CLI.hpp>

#include "core/result.h"
#include "hal/registry.h"

namespace commonlight::apps {

// Exit codes (docs/cli.md).
inline constexpr int kExitOk = 0;
inline constexpr int kExitUsage = 2;
inline constexpr int kExitBadInput = 3;
inline constexpr int kExitDevice = 4;

// Set by a subcommand's parse callback: the work to do once parsing succeeded.
using Runner = std::function<int()>;

void addCamerasCommand(CLI::App& app, Runner& runner);
void addRecordCommand(CLI::App& app, Runner& runner);
void addPlayCommand(CLI::App& app, Runner& runner);
void addLiveCommand(CLI::App& app, Runner& runner);
void addSimCommand(CLI::App& app, Runner& runner);
void addCalibrateCommand(CLI::App& app, Runner& runner);
void addTrackCommand(CLI::App& app, Runner& runner);
void addBenchCommand(CLI::App& app, Runner& runner);
void addServeGigeCommand(CLI::App& app, Runner& runner);
void addCalibrateResponseCommand(CLI::App& app, Runner& runner);
void addPlotCommand(CLI::App& app, Runner& runner);

// Prints "commonlight: error: <message>" and returns the exit code for the error.
int reportError(const Error& error);
// play's and live's real-time options: --lighting-every N and --fixed-quality.
void addRealTimeOptions(CLI::App& sub, int& lighting_every, bool& fixed_quality);

// Every camera backend this build has (hardware and mocks).
hal::CameraRegistry makeCameraRegistry();

// Stop requested by SIGINT or SIGTERM. installStopSignals() must run before any thread starts:
// it blocks the signals in every thread and waits for them on a dedicated thread.
void installStopSignals();
std::stop_token stopToken();

}  // namespace commonlight::apps
