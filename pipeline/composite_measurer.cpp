#include "pipeline/composite_measurer.h"

#include <utility>

#include "core/log.h"
#include "core/thread_priority.h"

namespace commonlight::pipeline {

CompositeMeasurer::CompositeMeasurer(const Sequence& sequence, const ResponseCurve& response,
                                     const CompositeMeasurerOptions& options)
    : sequence_(sequence), response_(response), options_(options) {
    if (options_.buffers == 0) options_.buffers = 1;
}

CompositeMeasurer::~CompositeMeasurer() { (void)finish(); }

Result<void> CompositeMeasurer::measure(const ImageView& composite, std::int64_t timestamp_ns, double exposure_gain) {
    CL_TRY(std::optional<FrameTruth> truth, readFrameTruth(sequence_, timestamp_ns));
    if (truth) errors_.add(composite, truth->composite.view(), truth->changed.view(), response_, exposure_gain);
    return {};
}

Result<void> CompositeMeasurer::add(const ImageView& composite, std::int64_t timestamp_ns, double exposure_gain) {
    if (!options_.background) return measure(composite, timestamp_ns, exposure_gain);
    std::unique_lock lock(mutex_);
    if (error_) return fail(*error_);
    if (!thread_.joinable()) {
        // The thread's priority is the caller's plus `nice`, set by the thread itself.
        stopping_ = false;
        const int nice = currentThreadNice() + options_.nice;
        thread_ = std::thread([this, nice] {
            if (!setCurrentThreadNice(nice)) log::warning("composite measurement: could not lower its thread's priority");
            run();
        });
    }
    if (in_use_ >= options_.buffers) {
        ++unmeasured_;  // every buffer is waiting: the measurement is behind
        return {};
    }
    Job job;
    if (!spare_.empty()) {
        job.composite = std::move(spare_.back());
        spare_.pop_back();
    }
    ++in_use_;
    lock.unlock();
    job.composite.assign(composite);  // the copy outside the lock
    job.timestamp_ns = timestamp_ns;
    job.exposure_gain = exposure_gain;
    lock.lock();
    queue_.push_back(std::move(job));
    wake_.notify_one();
    return {};
}

void CompositeMeasurer::run() {
    std::unique_lock lock(mutex_);
    while (true) {
        wake_.wait(lock, [&] { return !queue_.empty() || stopping_; });
        if (queue_.empty()) return;  // stopping, and everything measured
        Job job = std::move(queue_.front());
        queue_.pop_front();
        const bool skip = error_.has_value();  // after an error the run ends: no more measuring
        lock.unlock();
        Result<void> measured = skip ? Result<void>{} : measure(job.composite.view(), job.timestamp_ns, job.exposure_gain);
        lock.lock();
        if (!measured && !error_) error_ = measured.error();
        spare_.push_back(std::move(job.composite));
        --in_use_;
    }
}

Result<void> CompositeMeasurer::finish() {
    std::unique_lock lock(mutex_);
    if (thread_.joinable()) {
        stopping_ = true;
        wake_.notify_one();
        lock.unlock();
        thread_.join();
        lock.lock();
    }
    if (error_) return fail(*error_);
    return {};
}

}  // namespace commonlight::pipeline
