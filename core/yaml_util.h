// yaml-cpp helpers whose errors name the file, the line and the key at fault:
//     "calib.yaml:7: key 'camera_matrix.data': expected 9 numbers, found 8"
#pragma once

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "core/result.h"

namespace commonlight::yaml {

// Parses a YAML file. OpenCV FileStorage's "%YAML:1.0" first line (not valid YAML 1.2) is
// accepted. Syntax errors give file:line:column.
Result<YAML::Node> loadFile(const std::filesystem::path& file);
// Parses YAML text; `name` stands for the file in messages.
Result<YAML::Node> loadString(const std::string& text, const std::string& name);

// "file:line" of a node (1-based line; just "file" when the node has no position).
std::string where(const std::string& file, const YAML::Node& node);

// An error of code kBadInput: "<file>:<line>: key '<key>': <problem>".
Error keyError(const std::string& file, const YAML::Node& node, std::string_view key, std::string_view problem);

// Typed access to map entries. `key` may be dotted for messages ("camera_matrix.data"); the
// lookup itself uses the last component. `parent` is the enclosing map.
Result<double> getDouble(const std::string& file, const YAML::Node& parent, std::string_view key);
Result<int> getInt(const std::string& file, const YAML::Node& parent, std::string_view key);
Result<std::string> getString(const std::string& file, const YAML::Node& parent, std::string_view key);
// A sequence of numbers; `expected` < 0 accepts any length.
Result<std::vector<double>> getDoubles(const std::string& file, const YAML::Node& parent, std::string_view key,
                                       int expected = -1);
// Same, for a node already looked up (a list, or a scalar).
Result<std::vector<double>> asDoubles(const std::string& file, const YAML::Node& node, std::string_view key,
                                      int expected = -1);
Result<double> asDouble(const std::string& file, const YAML::Node& node, std::string_view key);

// The last component of a dotted key.
std::string_view leafKey(std::string_view key);

}  // namespace commonlight::yaml
