// libFuzzer harness for one reader of fuzz/readers.h, chosen at build time
// (COMMONLIGHT_FUZZ_READER="calibration"): every input is written to a file in a private temporary
// folder and read through the project's reader. The reader must return, and a failure must keep
// the contract (contractViolation): a contract broken is reported as a crash, like an ASan/UBSan
// finding or an exception escaping the reader.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "fuzz/readers.h"

#ifndef COMMONLIGHT_FUZZ_READER
#error "COMMONLIGHT_FUZZ_READER names the reader this harness drives"
#endif

namespace {

namespace fs = std::filesystem;

const commonlight::fuzz::Reader* g_reader = nullptr;
bool g_verbose = false;  // COMMONLIGHT_FUZZ_VERBOSE=1: print every result (fuzz_x FILE... to see them)
fs::path g_dir;          // this process's temporary folder
fs::path g_file;         // the input, rewritten for every run

void removeDir() {
    std::error_code ec;
    fs::remove_all(g_dir, ec);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
    g_reader = commonlight::fuzz::findReader(COMMONLIGHT_FUZZ_READER);
    if (g_reader == nullptr) {
        std::fprintf(stderr, "fuzz: no reader named '%s'\n", COMMONLIGHT_FUZZ_READER);
        std::abort();
    }
    std::string pattern = (fs::temp_directory_path() / "commonlight-fuzz-XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) {
        std::perror("fuzz: mkdtemp");
        std::abort();
    }
    g_dir = pattern;
    g_verbose = std::getenv("COMMONLIGHT_FUZZ_VERBOSE") != nullptr;
    g_file = g_dir / ("input" + std::string(g_reader->extension));
    std::atexit(removeDir);
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    std::FILE* out = std::fopen(g_file.c_str(), "wb");
    if (out == nullptr || (size > 0 && std::fwrite(data, 1, size, out) != size) || std::fclose(out) != 0) {
        std::perror("fuzz: writing the input file");
        std::abort();
    }
    const commonlight::Result<void> result = g_reader->read(g_file);
    if (g_verbose)
        std::fprintf(stderr, "fuzz_%s: %s\n", COMMONLIGHT_FUZZ_READER,
                     result ? "read" : result.error().message.c_str());
    const std::string violation = commonlight::fuzz::contractViolation(*g_reader, g_file, result);
    if (!violation.empty()) {
        std::fprintf(stderr, "fuzz_%s: reader contract broken: %s\n", COMMONLIGHT_FUZZ_READER, violation.c_str());
        std::abort();
    }
    return 0;
}
