// Replays every seed and every input a fuzzer ever crashed a reader with (tests/fuzz/regressions/
// <harness>/, kept by scripts/fuzz) through the reader, in the normal build and so under
// ASan/UBSan in scripts/test. A regression input must give an error value of the reader's
// bad-input code that names the file; a seed (fuzz/seeds.txt, fuzz/seeds/) must read; no input
// may crash or throw.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "fuzz/readers.h"
#include "tests/test_support.h"

namespace commonlight {
namespace {

namespace fs = std::filesystem;
using fuzz::Reader;
using testing::sourceDir;

std::vector<fs::path> filesIn(const fs::path& dir) {
    std::vector<fs::path> files;
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) return files;
    for (const auto& entry : fs::recursive_directory_iterator(dir)) {
        if (entry.is_regular_file() && entry.path().filename().string().front() != '.') files.push_back(entry.path());
    }
    std::sort(files.begin(), files.end());
    return files;
}

// The repository files fuzz/seeds.txt lists for `harness`.
std::vector<fs::path> listedSeeds(std::string_view harness) {
    std::ifstream in(sourceDir() / "fuzz/seeds.txt");
    EXPECT_TRUE(in) << "fuzz/seeds.txt";
    std::vector<fs::path> files;
    std::string line;
    while (std::getline(in, line)) {
        if (line.empty() || line.front() == '#') continue;
        std::istringstream fields(line);
        std::string name, path;
        fields >> name >> path;
        if (name != harness) continue;
        const fs::path full = sourceDir() / path;
        if (fs::is_directory(full)) {
            for (const auto& f : filesIn(full)) files.push_back(f);
        } else {
            EXPECT_TRUE(fs::is_regular_file(full)) << "fuzz/seeds.txt lists " << path << ", which does not exist";
            files.push_back(full);
        }
    }
    return files;
}

class Replay : public ::testing::TestWithParam<const Reader*> {};

// The seeds are valid inputs: a seed that does not read starts the fuzzer in the wrong place.
TEST_P(Replay, SeedsRead) {
    const Reader& reader = *GetParam();
    auto seeds = listedSeeds(reader.name);
    for (const fs::path& file : filesIn(sourceDir() / "fuzz/seeds" / reader.name)) seeds.push_back(file);
    for (const fs::path& file : seeds) {
        const Result<void> result = reader.read(file);
        EXPECT_TRUE(result) << file << ": " << (result ? "" : result.error().message);
    }
}

// A regression input is bad input unless its name says ".valid." (a valid file that crashed a
// reader, like a deep glTF node chain): then it must read.
TEST_P(Replay, RegressionsAreErrorsNamingTheFile) {
    const Reader& reader = *GetParam();
    const auto files = filesIn(sourceDir() / "tests/fuzz/regressions" / reader.name);
    for (const fs::path& file : files) {
        const Result<void> result = reader.read(file);
        if (file.filename().string().find(".valid.") != std::string::npos) {
            EXPECT_TRUE(result) << file << ": " << (result ? "" : result.error().message);
            continue;
        }
        ASSERT_FALSE(result) << file << ": read without an error";
        EXPECT_EQ(fuzz::contractViolation(reader, file, result), "") << file;
    }
    if (files.empty()) GTEST_LOG_(INFO) << "no regression inputs for " << reader.name;
}

INSTANTIATE_TEST_SUITE_P(Readers, Replay, ::testing::ValuesIn([] {
                             std::vector<const Reader*> all;
                             for (const Reader& r : fuzz::readers()) all.push_back(&r);
                             return all;
                         }()),
                         [](const auto& p) { return std::string(p.param->name); });

// Every harness has a dictionary and seeds to start from.
TEST(Replay, EveryReaderHasSeedsAndADictionary) {
    for (const Reader& reader : fuzz::readers()) {
        EXPECT_TRUE(fs::is_regular_file(sourceDir() / "fuzz/dict" / (std::string(reader.name) + ".dict")))
            << reader.name;
        EXPECT_FALSE(listedSeeds(reader.name).empty() && filesIn(sourceDir() / "fuzz/seeds" / reader.name).empty())
            << reader.name << " has no seeds";
    }
}

}  // namespace
}  // namespace commonlight
