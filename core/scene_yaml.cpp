#include "core/scene_yaml.h"

#include <cctype>
#include <cmath>
#include <sstream>

#include "core/yaml_util.h"

namespace commonlight::yaml {

namespace {

constexpr double kUnitQuaternionTolerance = 1e-6;

// The key node of `name` in a transform map, for messages that point at that key's line.
Error transformError(const std::string& file, const YAML::Node& node, std::string_view key, std::string_view name,
                     std::string_view problem) {
    return keyError(file, findKey(node, name), joinKey(key, name), problem);
}

}  // namespace

bool present(const YAML::Node& map, std::string_view key) { return map.IsMap() && map[std::string(key)].IsDefined(); }

Result<Rigid3d> asTransform(const std::string& file, const YAML::Node& node, std::string_view key) {
    CL_TRY_VOID(checkKeys(file, node, key, {"t", "rpy_deg", "q_wxyz", "matrix"}));
    const bool has_t = present(node, "t");
    const bool has_rpy = present(node, "rpy_deg");
    const bool has_q = present(node, "q_wxyz");
    if (present(node, "matrix")) {
        if (has_t || has_rpy || has_q) {
            const char* other = has_t ? "t" : (has_rpy ? "rpy_deg" : "q_wxyz");
            return fail(transformError(file, node, key, other,
                                       "a transform with a matrix takes nothing else (the matrix holds rotation and "
                                       "translation)"));
        }
        CL_TRY(const std::vector<double> m, getDoubles(file, node, joinKey(key, "matrix"), 16));
        const Eigen::Matrix<double, 4, 4, Eigen::RowMajor> matrix(m.data());
        auto pose = Rigid3d::fromMatrix(matrix);
        if (!pose) {
            return fail(transformError(file, node, key, "matrix", "not a rigid transform: " + pose.error().message));
        }
        return *pose;
    }
    if (has_rpy && has_q) {
        return fail(transformError(file, node, key, "q_wxyz", "give one rotation: rpy_deg or q_wxyz, not both"));
    }
    if (!has_t) {
        return fail(keyError(file, node, joinKey(key, "t"),
                             "missing (a transform is t with optional rpy_deg or q_wxyz, or a matrix)"));
    }
    CL_TRY(const std::vector<double> t, getDoubles(file, node, joinKey(key, "t"), 3));
    const Eigen::Vector3d translation(t[0], t[1], t[2]);
    if (has_rpy) {
        CL_TRY(const std::vector<double> rpy, getDoubles(file, node, joinKey(key, "rpy_deg"), 3));
        return Rigid3d::fromRpyDeg(translation, Eigen::Vector3d(rpy[0], rpy[1], rpy[2]));
    }
    if (has_q) {
        CL_TRY(const std::vector<double> q, getDoubles(file, node, joinKey(key, "q_wxyz"), 4));
        const Eigen::Quaterniond rotation(q[0], q[1], q[2], q[3]);
        const double norm = rotation.norm();
        if (!(std::abs(norm - 1.0) <= kUnitQuaternionTolerance)) {
            std::ostringstream msg;
            msg.precision(7);
            msg << "quaternion has length " << norm << ", it must be a unit quaternion (within "
                << kUnitQuaternionTolerance << ")";
            return fail(transformError(file, node, key, "q_wxyz", msg.str()));
        }
        return Rigid3d(rotation, translation);  // normalises the rounding left in the file's digits
    }
    return Rigid3d(Eigen::Quaterniond::Identity(), translation);
}

Result<Rigid3d> getTransform(const std::string& file, const YAML::Node& parent, std::string_view key) {
    const YAML::Node node = parent[std::string(leafKey(key))];
    if (!node.IsDefined() || node.IsNull()) return fail(keyError(file, parent, key, "missing"));
    return asTransform(file, node, key);
}

Result<double> getPositive(const std::string& file, const YAML::Node& parent, std::string_view key) {
    CL_TRY(const double value, getDouble(file, parent, key));
    if (!(value > 0.0)) {
        return fail(
            keyError(file, parent[std::string(leafKey(key))], key, "must be positive, found " + formatNumber(value)));
    }
    return value;
}

Result<std::vector<double>> getPositives(const std::string& file, const YAML::Node& parent, std::string_view key,
                                         int count) {
    CL_TRY(const std::vector<double> values, getDoubles(file, parent, key, count));
    const YAML::Node node = parent[std::string(leafKey(key))];
    for (std::size_t i = 0; i < values.size(); ++i) {
        if (!(values[i] > 0.0)) {
            return fail(
                keyError(file, node[i], indexKey(key, i), "must be positive, found " + formatNumber(values[i])));
        }
    }
    return values;
}

Result<Eigen::Vector3d> asRgb(const std::string& file, const YAML::Node& node, std::string_view key, double max) {
    Eigen::Vector3d rgb;
    if (node.IsScalar()) {
        CL_TRY(const double grey, asDouble(file, node, key));
        rgb.setConstant(grey);
    } else if (node.IsSequence()) {
        CL_TRY(const std::vector<double> values, asDoubles(file, node, key, 3));
        rgb = Eigen::Vector3d(values[0], values[1], values[2]);
    } else {
        return fail(keyError(file, node, key, "expected a number or [r, g, b]"));
    }
    for (int c = 0; c < 3; ++c) {
        if (rgb[c] < 0.0 || rgb[c] > max) {
            const std::string range =
                std::isinf(max) ? "must not be negative" : "must be in [0, " + formatNumber(max) + "]";
            return fail(keyError(file, node, key, range + ", found " + formatNumber(rgb[c])));
        }
    }
    return rgb;
}

Result<RgbOrEstimate> asRgbOrEstimate(const std::string& file, const YAML::Node& node, std::string_view key,
                                      double max) {
    if (node.IsScalar() && node.Scalar() == "estimate") return RgbOrEstimate::estimate();
    // A word other than `estimate` (a typo of it, most likely) gets the full list of choices.
    const bool word = node.IsScalar() && !node.Scalar().empty() &&
                      std::isalpha(static_cast<unsigned char>(node.Scalar().front())) != 0;
    if (node.IsMap() || word) {
        return fail(keyError(
            file, node, key,
            "expected a number, [r, g, b] or estimate" + (word ? ", found '" + node.Scalar() + "'" : std::string())));
    }
    CL_TRY(const Eigen::Vector3d rgb, asRgb(file, node, key, max));
    return RgbOrEstimate::constant(rgb);
}

std::string formatList(const double* values, int count) {
    std::string out = "[";
    for (int i = 0; i < count; ++i) {
        if (i > 0) out += ", ";
        out += formatNumber(values[i]);
    }
    return out + "]";
}

std::string formatTransform(const Rigid3d& pose) {
    std::string out = "{t: " + formatList(pose.translation.data(), 3);
    const Eigen::Quaterniond& q = pose.rotation;
    if (!(q.w() == 1.0 && q.x() == 0.0 && q.y() == 0.0 && q.z() == 0.0)) {
        const double wxyz[4] = {q.w(), q.x(), q.y(), q.z()};
        out += ", q_wxyz: " + formatList(wxyz, 4);
    }
    return out + "}";
}

std::string formatRgb(const Eigen::Vector3d& rgb) {
    if (rgb[0] == rgb[1] && rgb[1] == rgb[2]) return formatNumber(rgb[0]);
    return formatList(rgb.data(), 3);
}

std::string formatRgbOrEstimate(const RgbOrEstimate& value) {
    return value.value ? formatRgb(*value.value) : std::string("estimate");
}

}  // namespace commonlight::yaml
