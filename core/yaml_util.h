// yaml-cpp helpers whose errors name the file, the line and the key at fault:
//     "calib.yaml:7: key 'camera_matrix.data': expected 9 numbers, found 8"
#pragma once

#include <filesystem>
#include <initializer_list>
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

// Key paths for messages: joinKey("real[2]", "t") is "real[2].t", joinKey("", "camera") is "camera";
// indexKey("real", 2) is "real[2]".
std::string joinKey(std::string_view parent, std::string_view key);
std::string indexKey(std::string_view parent, std::size_t index);

// The key node of entry `key` of `map` (its line is the line of "key:"), or an undefined node.
YAML::Node findKey(const YAML::Node& map, std::string_view key);

// The entry `key` of `map`, or an undefined node when `map` is not a map or has no such entry.
// Unlike yaml-cpp's const operator[], it never throws (a scalar subscripted throws
// YAML::BadSubscript) and never gives the "zombie" node that yaml-cpp refuses to assign.
YAML::Node lookup(const YAML::Node& map, std::string_view key);

// Whether `map` is a map with a non-null entry `key`.
bool has(const YAML::Node& map, std::string_view key);

// Fails when `node` is not a map, when one of its keys is not in `allowed` ("<file>:<line>: key
// 'real[2].rpy': unknown key (expected t, rpy_deg, q_wxyz or matrix)"), is not a plain scalar, or
// appears twice. `path` is the key path of the map itself ("" for the document root).
Result<void> checkKeys(const std::string& file, const YAML::Node& node, std::string_view path,
                       std::initializer_list<std::string_view> allowed);

// A required entry that must be a map, or a list. `key` as for getDouble.
Result<YAML::Node> getMap(const std::string& file, const YAML::Node& parent, std::string_view key);
Result<YAML::Node> getList(const std::string& file, const YAML::Node& parent, std::string_view key);

// The shortest text that reads back as the same double (never more than 17 significant digits,
// like "%.17g"): "0.1", "1", "1e-20"; ".nan", ".inf", "-.inf" for the non-finite.
std::string formatNumber(double value);
// Same, with a trailing "." on integral values ("1.", "-0.") as OpenCV writes them, so the value
// stays a floating-point number for any reader.
std::string formatDouble(double value);
// A YAML scalar for `text`: plain when that reads back as the same string, otherwise double-quoted.
std::string quoteString(std::string_view text);

}  // namespace commonlight::yaml
