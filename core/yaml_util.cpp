#include "core/yaml_util.h"

#include <charconv>
#include <cmath>
#include <fstream>
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
    // yaml-cpp's as<double> accepts "1.0abc"; be strict. Also accept .inf/.nan spellings.
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

}  // namespace commonlight::yaml
