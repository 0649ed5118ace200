// Helper of the GigE integration tests (tests/e2e/aravis_*.sh):
//   gige_sequence_tool make OUT FRAMES WIDTH HEIGHT gray8|gray16|rgb8 RATE
//       writes a sequence whose every frame is different (its index is in its pixels)
//   gige_sequence_tool compare SERVED RECORDED [MIN_FRAMES]
//       checks that every recorded frame is bit-identical to a frame serve-gige sends for
//       SERVED, and that they come in order: the served frame advances exactly with the device
//       sequence number in meta.csv (a lost frame is a gap in both), wrapping when looping.
// Exit 0 when it holds, 1 (with the reason) when not, 2 on usage errors.
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/frame_file.h"
#include "core/image.h"
#include "core/sequence_io.h"
#include "core/sequence_writer.h"
#include "mocks/gige/gige_server.h"

using namespace commonlight;

namespace {

int failWith(const std::string& message) {
    std::fprintf(stderr, "gige_sequence_tool: %s\n", message.c_str());
    return 1;
}

std::uint64_t hashPixels(const ImageView& v) {
    std::uint64_t h = 1469598103934665603ull;  // FNV-1a over rows (padding ignored)
    const std::size_t row = minStride(v.format, v.width);
    for (int y = 0; y < v.height; ++y) {
        const std::uint8_t* p = v.row(y);
        for (std::size_t i = 0; i < row; ++i) h = (h ^ p[i]) * 1099511628211ull;
    }
    return h;
}

int make(const std::string& out, int frames, int width, int height, const std::string& format_name, double rate) {
    const auto format = parsePixelFormat(format_name);
    if (!format) return failWith("unknown format " + format_name);
    SensorInfo sensor;
    sensor.rate_hz = rate;
    auto writer = SequenceWriter::create(out, sensor, SequenceWriterOptions{false});
    if (!writer) return failWith(writer.error().message);
    Image image(*format, width, height);
    for (int i = 0; i < frames; ++i) {
        const std::size_t row = minStride(*format, width);
        for (int y = 0; y < height; ++y) {
            std::uint8_t* p = image.data() + static_cast<std::size_t>(y) * image.stride();
            for (std::size_t x = 0; x < row; ++x) p[x] = static_cast<std::uint8_t>(x * 7 + y * 3 + i * 11 + (x ^ y));
        }
        // The index in the first bytes, so no two frames are alike.
        image.data()[0] = static_cast<std::uint8_t>(i);
        image.data()[1] = static_cast<std::uint8_t>(i >> 8);
        FrameMetadata meta;
        meta.sequence = static_cast<std::uint64_t>(i);
        meta.timestamp_ns = 1'000'000'000 + static_cast<std::int64_t>(i * 1e9 / rate);
        if (auto written = writer->write(image.view(), meta); !written) return failWith(written.error().message);
    }
    std::printf("wrote %d %s frames of %dx%d to %s\n", frames, format_name.c_str(), width, height, out.c_str());
    return 0;
}

int compare(const std::string& served_dir, const std::string& recorded_dir, std::size_t min_frames) {
    auto served = readSequence(served_dir);
    if (!served) return failWith(served.error().message);
    auto recorded = readSequence(recorded_dir);
    if (!recorded) return failWith(recorded.error().message);
    PixelFormat stored = served->sensor.pixel_format;
    FrameFileReader reader;
    if (stored == PixelFormat::kInvalid) {
        Image probe;
        if (auto r = reader.read(served->framePath(0), stored, 0, 0, probe); !r) return failWith(r.error().message);
        stored = probe.format();
    }
    std::unordered_map<std::uint64_t, std::size_t> index_of;
    std::vector<Image> served_frames(served->frames.size());
    for (std::size_t i = 0; i < served->frames.size(); ++i) {
        if (auto d = mocks::decodeForServing(reader, *served, i, stored, served_frames[i]); !d) {
            return failWith(d.error().message);
        }
        index_of.emplace(hashPixels(served_frames[i].view()), i);
    }
    if (recorded->frames.size() < min_frames) {
        return failWith(recorded_dir + " holds " + std::to_string(recorded->frames.size()) + " frames, expected at least " +
                        std::to_string(min_frames));
    }
    // Frames lost on the way (at the device, or dropped by a slow recorder) are allowed, but
    // must show as gaps in the device's sequence numbers: the served frame advances exactly
    // with the device frame counter (one per frame sent).
    const auto sequenceOf = [&](std::size_t k) -> std::optional<std::uint64_t> {
        if (k < recorded->meta.size() && recorded->meta[k]) return recorded->meta[k]->sequence;
        return std::nullopt;
    };
    std::size_t first_index = 0;
    std::uint64_t gaps = 0;
    Image frame;
    for (std::size_t k = 0; k < recorded->frames.size(); ++k) {
        if (auto r = reader.read(recorded->framePath(k), recorded->sensor.pixel_format, 0, 0, frame); !r) {
            return failWith(r.error().message);
        }
        const auto found = index_of.find(hashPixels(frame.view()));
        if (found == index_of.end() || !samePixels(frame.view(), served_frames[found->second].view())) {
            return failWith(recorded->framePath(k).string() + " (frame " + std::to_string(k) +
                            ") is not bit-identical to any served frame");
        }
        const auto seq = sequenceOf(k);
        const auto seq0 = sequenceOf(0);
        if (!seq || !seq0) return failWith(recorded_dir + ": meta.csv has no row for frame " + std::to_string(k));
        if (k == 0) {
            first_index = found->second;
        } else {
            const auto prev = sequenceOf(k - 1);
            if (*seq <= *prev) return failWith("sequence numbers do not increase at recorded frame " + std::to_string(k));
            gaps += *seq - *prev - 1;
            const std::size_t expected = (first_index + (*seq - *seq0)) % served_frames.size();
            if (found->second != expected) {
                return failWith("recorded frame " + std::to_string(k) + " (device sequence " + std::to_string(*seq) +
                                ") is served frame " + std::to_string(found->second) + ", expected " +
                                std::to_string(expected));
            }
        }
    }
    std::printf("%zu recorded frames are bit-identical to served frames, in order (%llu lost on the way, "
                "counted as sequence gaps)\n",
                recorded->frames.size(), static_cast<unsigned long long>(gaps));
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    const std::vector<std::string> args(argv + 1, argv + argc);
    if (args.size() == 7 && args[0] == "make") {
        return make(args[1], std::atoi(args[2].c_str()), std::atoi(args[3].c_str()), std::atoi(args[4].c_str()), args[5],
                    std::atof(args[6].c_str()));
    }
    if ((args.size() == 3 || args.size() == 4) && args[0] == "compare") {
        return compare(args[1], args[2], args.size() == 4 ? std::strtoull(args[3].c_str(), nullptr, 10) : 1);
    }
    std::fprintf(stderr, "usage: gige_sequence_tool make OUT FRAMES W H FORMAT RATE | compare SERVED RECORDED [MIN]\n");
    return 2;
}
