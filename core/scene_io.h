// Reading and writing scene files (YAML; docs/formats-scene.md). Every error names the file, the
// line and the key path: "scene.yaml:12: key 'real[2].world_from_object.rpy': unknown key (expected
// t, rpy_deg, q_wxyz or matrix)". Code kBadInput for malformed contents; kNotFound when the scene
// file, or a calibration or mesh file it names, does not exist.
#pragma once

#include <filesystem>
#include <string>

#include "core/result.h"
#include "core/scene.h"

namespace commonlight {

struct SceneReadOptions {
    bool load_camera = true;  // read the calibration file named by `camera` into Scene::camera
    bool load_meshes = true;  // read every mesh file into MeshShape::mesh
};

// Reads and validates a scene. Relative paths in it (camera, meshes) are resolved against the
// scene file's folder.
Result<Scene> readScene(const std::filesystem::path& file, const SceneReadOptions& options = {});
// Same, from text: `file` names the text in messages and its folder resolves relative paths.
Result<Scene> parseScene(const std::string& text, const std::filesystem::path& file,
                         const SceneReadOptions& options = {});

// Writes a scene that readScene reads back to the same values (numbers round-trip exactly;
// rotations are written as unit quaternions). Paths are written relative to the new file's folder.
// Scene::camera is not written, only Scene::camera_path. Atomic: temp file + rename.
Result<void> writeScene(const std::filesystem::path& file, const Scene& scene);
// The text writeScene writes, with paths relative to `base_dir`.
std::string formatScene(const Scene& scene, const std::filesystem::path& base_dir);

}  // namespace commonlight
