// Helpers shared by the tests: scratch folders and paths into the source tree.
#pragma once

#include <filesystem>
#include <string>

namespace commonlight::testing {

// A fresh folder under the system temp dir, removed (with its contents) when destroyed.
class TempDir {
public:
    TempDir();
    ~TempDir();
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    const std::filesystem::path& path() const { return path_; }
    std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

private:
    std::filesystem::path path_;
};

// The repository root (COMMONLIGHT_SOURCE_DIR, set by CTest).
std::filesystem::path sourceDir();
// Writes text to a file, creating parent folders.
void writeText(const std::filesystem::path& file, const std::string& text);
std::string readText(const std::filesystem::path& file);

}  // namespace commonlight::testing
