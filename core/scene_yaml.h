// YAML pieces of the scene format: transforms, colours and checked numbers, read with errors that
// give "<file>:<line>: key '<path>': <problem>" (code kBadInput), and written back as text.
// `key` arguments are full key paths ("real[2].world_from_object"); lookups use the last component.
#pragma once

#include <string>
#include <string_view>

#include <Eigen/Core>
#include <yaml-cpp/yaml.h>

#include "core/pose.h"
#include "core/result.h"
#include "core/scene.h"

namespace commonlight::yaml {

// A transform map, exactly one of:
//   {t: [x, y, z]}                            translation only
//   {t: [...], rpy_deg: [roll, pitch, yaw]}   R = Rz(yaw) * Ry(pitch) * Rx(roll), degrees
//   {t: [...], q_wxyz: [w, x, y, z]}          unit quaternion (|q| within 1e-6 of 1)
//   {matrix: [16 numbers]}                    row-major 4x4, rigid (Rigid3d::fromMatrix)
Result<Rigid3d> asTransform(const std::string& file, const YAML::Node& node, std::string_view key);
Result<Rigid3d> getTransform(const std::string& file, const YAML::Node& parent, std::string_view key);

// A number > 0.
Result<double> getPositive(const std::string& file, const YAML::Node& parent, std::string_view key);
// `count` numbers, each > 0.
Result<std::vector<double>> getPositives(const std::string& file, const YAML::Node& parent, std::string_view key,
                                         int count);

// An RGB value: a number (grey) or [r, g, b], every channel in [0, max].
Result<Eigen::Vector3d> asRgb(const std::string& file, const YAML::Node& node, std::string_view key, double max);
// The same, or the word `estimate`.
Result<RgbOrEstimate> asRgbOrEstimate(const std::string& file, const YAML::Node& node, std::string_view key,
                                      double max);

// Whether `map` has the key at all (even with an empty value): for keys whose presence matters.
bool present(const YAML::Node& map, std::string_view key);

// Writers. Numbers are written so that they read back as the same doubles.
std::string formatTransform(const Rigid3d& pose);   // {t: [...]} or {t: [...], q_wxyz: [...]}
std::string formatRgb(const Eigen::Vector3d& rgb);  // a number when all channels are equal
std::string formatRgbOrEstimate(const RgbOrEstimate& value);
std::string formatList(const double* values, int count);  // [a, b, c]

}  // namespace commonlight::yaml
