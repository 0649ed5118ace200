// commonlight serve-gige --sequence SEQ [--address 127.0.0.1] [--frames N] [--loop] [--rate HZ]:
// serves a recorded sequence as a GigE Vision camera (mocks/gige), so that any GigE client can
// watch it. Runs until the sequence (or --frames) is done, or Ctrl-C / SIGTERM.
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>

#include "apps/app.h"
#include "apps/quiet.h"
#include "core/log.h"
#ifdef COMMONLIGHT_HAVE_ARAVIS
#include "mocks/gige/gige_server.h"
#endif

namespace commonlight::apps {

namespace {

struct ServeGigeOptions {
    std::string sequence;
    std::string address = "127.0.0.1";
    std::uint64_t frames = 0;
    bool loop = false;
    double rate = 0.0;
};

int runServeGige([[maybe_unused]] const ServeGigeOptions& options) {
#ifdef COMMONLIGHT_HAVE_ARAVIS
    mocks::GigeServerOptions server_options;
    server_options.sequence = options.sequence;
    server_options.address = options.address;
    server_options.frames = options.frames;
    server_options.loop = options.loop;
    server_options.rate_hz = options.rate;
    auto server = mocks::GigeServer::start(server_options);
    if (!server) return reportError(server.error());
    const mocks::GigeServer& s = **server;
    say("serving %s as GigE Vision camera %s at %s: %s, %zu frames%s\n", options.sequence.c_str(),
                s.deviceId().c_str(), s.address().c_str(), hal::describe(s.format()).c_str(), s.sequenceFrames(),
                options.loop ? ", looping" : "");
    say("watch it with: commonlight record --camera aravis:%s ...\n", s.address().c_str());
    std::fflush(stdout);
    const std::stop_token stop = stopToken();
    while (!stop.stop_requested() && !s.finished()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (s.finished()) {
        // Let the last frame's packets (and any resend they need) go out before closing.
        for (int i = 0; i < 25 && !stop.stop_requested(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    const unsigned long long served = s.framesServed();
    server->reset();
    say("served %llu frames\n", served);
    return kExitOk;
#else
    return reportError(Error{ErrorCode::kUnsupported, "serve-gige: this build has no Aravis (libaravis-dev)"});
#endif
}

}  // namespace

void addServeGigeCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<ServeGigeOptions>();
    CLI::App* sub = app.add_subcommand("serve-gige", "Serve a recorded sequence as a GigE Vision camera (docs/cameras-aravis.md)");
    sub->add_option("--sequence", options->sequence, "Sequence folder to serve")->required();
    sub->add_option("--address", options->address, "Local IPv4 address (or interface) to serve on")->capture_default_str();
    sub->add_option("--frames", options->frames, "Stop after sending N frames (default: the sequence once, or forever with --loop)");
    sub->add_flag("--loop", options->loop, "Start again after the last frame");
    sub->add_option("--rate", options->rate, "Frames per second (default: the sequence's rate_hz, else 30)")
        ->check(CLI::PositiveNumber);
    sub->callback([options, &runner] { runner = [options] { return runServeGige(*options); }; });
}

}  // namespace commonlight::apps
