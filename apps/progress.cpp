#include "apps/progress.h"

#include <cstdio>

#include <unistd.h>

#include "apps/quiet.h"
#include "core/clock.h"

namespace commonlight::apps {

Progress::Progress(std::string label, std::uint64_t total)
    : label_(std::move(label)), total_(total), enabled_(isatty(STDERR_FILENO) == 1 && !quiet()), start_ns_(monotonicNowNs()) {}

Progress::~Progress() { finish(); }

void Progress::update(std::uint64_t done) {
    if (!enabled_) return;
    const std::int64_t now = monotonicNowNs();
    if (drawn_ && now - last_draw_ns_ < 100'000'000 && done != total_) return;
    last_draw_ns_ = now;
    drawn_ = true;
    if (total_ == 0) {
        std::fprintf(stderr, "\r%s  %llu frames ", label_.c_str(), static_cast<unsigned long long>(done));
        return;
    }
    constexpr int kWidth = 30;
    const double fraction = done >= total_ ? 1.0 : static_cast<double>(done) / static_cast<double>(total_);
    const int filled = static_cast<int>(fraction * kWidth);
    char bar[kWidth + 1];
    for (int i = 0; i < kWidth; ++i) bar[i] = i < filled ? '=' : ' ';
    bar[kWidth] = '\0';
    const double elapsed_s = static_cast<double>(now - start_ns_) / 1e9;
    const double eta_s = fraction > 0 ? elapsed_s * (1.0 - fraction) / fraction : 0.0;
    std::fprintf(stderr, "\r%s  %llu/%llu %3.0f%% [%s]  ETA %.0f s ", label_.c_str(), static_cast<unsigned long long>(done),
                 static_cast<unsigned long long>(total_), fraction * 100.0, bar, eta_s);
}

void Progress::finish() {
    if (!drawn_) return;
    std::fprintf(stderr, "\r\033[K");
    drawn_ = false;
}

}  // namespace commonlight::apps
