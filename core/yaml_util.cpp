#include "core/yaml_util.h"

#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>

namespace commonlight::yaml {

namespace {

std::string stripOpenCvDirective(std::string text) {
    // OpenCV writes "%YAML:1.0" (or "%YAML 1.0") and sometimes a "---" after it. YAML 1.2
    // parsers reject the colon form; the directive carries nothing we need.
    if (text.rfind("%YAML", 0) == 0) {
        const auto eol = text.find('\n');
        text.replace(0, eol == std::string::npos ? text.size() : eol, "");
    }
    return text;
}

bool parseNumber(const std::string& s, double& out) {
    // yaml-cpp's as<double> accepts "1.0abc"; be strict. Also accept the YAML (and OpenCV) spellings
    // of infinity and NaN, so that callers can say "must be finite" instead of "not a number".
    for (const char* nan : {".nan", ".NaN", ".NAN", ".Nan"}) {
        if (s == nan) {
            out = std::numeric_limits<double>::quiet_NaN();
            return true;
        }
    }
    for (const char* inf : {".inf", ".Inf", ".INF", "+.inf", "+.Inf", "+.INF", "-.inf", "-.Inf", "-.INF"}) {
        if (s == inf) {
            out = s.front() == '-' ? -std::numeric_limits<double>::infinity() : std::numeric_limits<double>::infinity();
            return true;
        }
    }
    const char* begin = s.data();
    const char* end = s.data() + s.size();
    while (begin < end && *begin == '+') ++begin;
    const auto [ptr, ec] = std::from_chars(begin, end, out);
    return ec == std::errc() && ptr == end;
}

}  // namespace

Result<YAML::Node> loadString(const std::string& text, const std::string& name) {
    try {
        return YAML::Load(stripOpenCvDirective(text));
    } catch (const YAML::Exception& e) {
        std::ostringstream msg;
        msg << name;
        if (!e.mark.is_null()) msg << ":" << e.mark.line + 1 << ":" << e.mark.column + 1;
        msg << ": YAML syntax error: " << e.msg;
        return fail(ErrorCode::kBadInput, msg.str());
    }
}

Result<YAML::Node> loadFile(const std::filesystem::path& file) {
    std::ifstream in(file, std::ios::binary);
    if (!in) {
        std::error_code ec;
        const bool exists = std::filesystem::exists(file, ec);
        return fail(exists ? ErrorCode::kIo : ErrorCode::kNotFound,
                    file.string() + (exists ? ": cannot be read" : ": no such file"));
    }
    std::ostringstream ss;
    ss << in.rdbuf();
    return loadString(ss.str(), file.string());
}

std::string where(const std::string& file, const YAML::Node& node) {
    if (!node.IsDefined() || node.Mark().is_null()) return file;
    return file + ":" + std::to_string(node.Mark().line + 1);
}

Error keyError(const std::string& file, const YAML::Node& node, std::string_view key, std::string_view problem) {
    std::string msg = where(file, node);
    msg += ": key '";
    msg += key;
    msg += "': ";
    msg += problem;
    return Error{ErrorCode::kBadInput, std::move(msg)};
}

std::string_view leafKey(std::string_view key) {
    const auto dot = key.rfind('.');
    return dot == std::string_view::npos ? key : key.substr(dot + 1);
}

namespace {

Result<YAML::Node> child(const std::string& file, const YAML::Node& parent, std::string_view key) {
    if (!parent.IsMap()) return fail(keyError(file, parent, key, "expected a map containing this key"));
    const YAML::Node node = parent[std::string(leafKey(key))];
    if (!node.IsDefined() || node.IsNull()) return fail(keyError(file, parent, key, "missing"));
    return node;
}

}  // namespace

Result<double> asDouble(const std::string& file, const YAML::Node& node, std::string_view key) {
    double value = 0.0;
    if (!node.IsScalar() || !parseNumber(node.Scalar(), value)) {
        return fail(keyError(file, node, key, "expected a number" +
                                                  (node.IsScalar() ? ", found '" + node.Scalar() + "'" : std::string())));
    }
    if (!std::isfinite(value)) return fail(keyError(file, node, key, "must be finite"));
    return value;
}

Result<double> getDouble(const std::string& file, const YAML::Node& parent, std::string_view key) {
    CL_TRY(const YAML::Node node, child(file, parent, key));
    return asDouble(file, node, key);
}

Result<int> getInt(const std::string& file, const YAML::Node& parent, std::string_view key) {
    CL_TRY(const YAML::Node node, child(file, parent, key));
    int value = 0;
    if (node.IsScalar()) {
        const std::string& s = node.Scalar();
        const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
        if (ec == std::errc() && ptr == s.data() + s.size()) return value;
    }
    return fail(keyError(file, node, key, "expected an integer"));
}

Result<std::string> getString(const std::string& file, const YAML::Node& parent, std::string_view key) {
    CL_TRY(const YAML::Node node, child(file, parent, key));
    if (!node.IsScalar()) return fail(keyError(file, node, key, "expected a string"));
    return node.Scalar();
}

Result<std::vector<double>> asDoubles(const std::string& file, const YAML::Node& node, std::string_view key,
                                      int expected) {
    if (!node.IsSequence()) return fail(keyError(file, node, key, "expected a list of numbers"));
    if (expected >= 0 && static_cast<int>(node.size()) != expected) {
        return fail(keyError(file, node, key,
                             "expected " + std::to_string(expected) + " numbers, found " + std::to_string(node.size())));
    }
    std::vector<double> values;
    values.reserve(node.size());
    for (std::size_t i = 0; i < node.size(); ++i) {
        CL_TRY(const double v, asDouble(file, node[i], std::string(key) + "[" + std::to_string(i) + "]"));
        values.push_back(v);
    }
    return values;
}

Result<std::vector<double>> getDoubles(const std::string& file, const YAML::Node& parent, std::string_view key,
                                       int expected) {
    CL_TRY(const YAML::Node node, child(file, parent, key));
    return asDoubles(file, node, key, expected);
}

std::string joinKey(std::string_view parent, std::string_view key) {
    std::string out(parent);
    if (!out.empty()) out += '.';
    out += key;
    return out;
}

std::string indexKey(std::string_view parent, std::size_t index) {
    std::string out(parent);
    out += '[';
    out += std::to_string(index);
    out += ']';
    return out;
}

YAML::Node findKey(const YAML::Node& map, std::string_view key) {
    if (!map.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
    for (auto it = map.begin(); it != map.end(); ++it) {
        const YAML::Node key_node = it->first;
        if (key_node.IsScalar() && key_node.Scalar() == key) return key_node;
    }
    return YAML::Node(YAML::NodeType::Undefined);
}

YAML::Node lookup(const YAML::Node& map, std::string_view key) {
    if (!map.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
    const YAML::Node node = map[std::string(key)];  // const: never inserts
    if (!node.IsDefined()) return YAML::Node(YAML::NodeType::Undefined);
    return node;
}

bool has(const YAML::Node& map, std::string_view key) {
    if (!map.IsMap()) return false;
    const YAML::Node node = map[std::string(key)];
    return node.IsDefined() && !node.IsNull();
}

Result<void> checkKeys(const std::string& file, const YAML::Node& node, std::string_view path,
                       std::initializer_list<std::string_view> allowed) {
    if (!node.IsMap()) {
        return fail(keyError(file, node, path.empty() ? std::string_view("(document)") : path, "expected a map"));
    }
    std::vector<std::string> seen;
    for (auto it = node.begin(); it != node.end(); ++it) {
        const YAML::Node key_node = it->first;  // a copy: the iterator hands out a temporary
        if (!key_node.IsScalar()) {
            return fail(keyError(file, key_node, path, "keys must be plain names, found a list or map as a key"));
        }
        const std::string& key = key_node.Scalar();
        const std::string key_path = joinKey(path, key);
        bool known = false;
        for (const std::string_view name : allowed) known = known || name == key;
        if (!known) {
            std::string expected;
            std::size_t i = 0;
            for (const std::string_view name : allowed) {
                if (i > 0) expected += (i + 1 == allowed.size()) ? " or " : ", ";
                expected += name;
                ++i;
            }
            return fail(keyError(file, key_node, key_path,
                                 allowed.size() == 0 ? "unknown key (this map takes no keys)"
                                                     : "unknown key (expected " + expected + ")"));
        }
        for (const std::string& other : seen) {
            // yaml-cpp keeps both entries of a repeated key and looks up the first: a silent surprise.
            if (other == key) return fail(keyError(file, key_node, key_path, "appears twice in the same map"));
        }
        seen.push_back(key);
    }
    return {};
}

Result<YAML::Node> getMap(const std::string& file, const YAML::Node& parent, std::string_view key) {
    CL_TRY(const YAML::Node node, child(file, parent, key));
    if (!node.IsMap()) return fail(keyError(file, node, key, "expected a map"));
    return node;
}

Result<YAML::Node> getList(const std::string& file, const YAML::Node& parent, std::string_view key) {
    CL_TRY(const YAML::Node node, child(file, parent, key));
    if (!node.IsSequence()) return fail(keyError(file, node, key, "expected a list"));
    return node;
}

std::string formatNumber(double value) {
    if (std::isnan(value)) return ".nan";
    if (std::isinf(value)) return value > 0 ? ".inf" : "-.inf";
    // Shortest representation that reads back as the same double (at most 17 significant digits).
    std::array<char, 64> buffer{};
    const auto [end, ec] = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
    return std::string(buffer.data(), ec == std::errc() ? end : buffer.data());
}

std::string formatDouble(double value) {
    std::string text = formatNumber(value);
    if (text.find_first_of(".eEn") == std::string::npos) text += '.';
    return text;
}

std::string quoteString(std::string_view text) {
    const auto plain_char = [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '.' ||
               c == '/' || c == '-' || c == '+';
    };
    bool plain = !text.empty() && text.front() != '-' && text != "null" && text != "Null" && text != "NULL";
    for (const char c : text) plain = plain && plain_char(c);
    if (plain) return std::string(text);
    std::string out = "\"";
    for (const char c : text) {
        switch (c) {
            case '"': out += "\\\""; break;
            case '\\': out += "\\\\"; break;
            case '\n': out += "\\n"; break;
            case '\t': out += "\\t"; break;
            default:
                if (static_cast<unsigned char>(c) < 0x20) {
                    std::array<char, 8> escape{};
                    std::snprintf(escape.data(), escape.size(), "\\x%02x", static_cast<unsigned>(c));
                    out += escape.data();
                } else {
                    out += c;
                }
        }
    }
    out += '"';
    return out;
}

}  // namespace commonlight::yaml
