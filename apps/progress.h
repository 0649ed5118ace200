// A one-line progress bar on stderr ("play  120/600  20% [=====     ]  ETA 16 s"), drawn only
// when stderr is a terminal and at most ten times a second. Pipeline thread only.
#pragma once

#include <cstdint>
#include <string>

namespace commonlight::apps {

class Progress {
public:
    // `total` 0: unknown (shows a count without percentage and ETA).
    Progress(std::string label, std::uint64_t total);
    ~Progress();
    Progress(const Progress&) = delete;
    Progress& operator=(const Progress&) = delete;

    void update(std::uint64_t done);
    // Clears the line (before printing a summary).
    void finish();

private:
    std::string label_;
    std::uint64_t total_;
    bool enabled_;
    bool drawn_ = false;
    std::int64_t start_ns_;
    std::int64_t last_draw_ns_ = 0;
};

}  // namespace commonlight::apps
