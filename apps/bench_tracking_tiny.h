// `commonlight bench tracking`, detection by size (issue 13, "detection at least 95% of the tags
// in view whose black square spans 7 px or more"): on a case's frames, every scene tag in view
// (by the true pose) is binned by the shorter span of its black square, and counted as detected
// by the tracker without and with the verification of predicted tags (tracking/tag_verify.h);
// beside it the camera pose error both ways, the verified corners' error and the step's cost.
#pragma once

#include <nlohmann/json.hpp>
#include <vector>

#include "core/camera_model.h"
#include "core/frame.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"
#include "core/scene.h"
#include "tracking/tracker.h"

namespace commonlight::apps {

struct DetectionBySizeInput {
    const std::vector<Image>* frames = nullptr;
    const std::vector<FrameMetadata>* meta = nullptr;
    const std::vector<Rigid3d>* cam_from_world_true = nullptr;  // at the instant the poses are for
    const CameraModel* camera = nullptr;
    const Scene* scene = nullptr;
};

// Runs the tracker (`base`, verify_predicted off and on), prints the table and returns its JSON.
Result<nlohmann::json> benchDetectionBySize(const DetectionBySizeInput& input, const tracking::TrackerOptions& base);

}  // namespace commonlight::apps
