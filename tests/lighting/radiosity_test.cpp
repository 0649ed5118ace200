// The radiosity solver against closed forms: the furnace (a closed room converges to
// Le / (1 - rho)), energy conservation of the links, a tiny element beside a huge one, and a box
// resting on a table (no light leaks under it, no self-shadowing from ray offsets).
#include "lighting/radiosity.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "lighting/direct.h"

namespace commonlight::lighting {
namespace {

using Eigen::Vector3d;

Scene boxRoom(const Vector3d& size) {
    Scene scene;
    RealObject room;
    room.name = "room";
    room.shape = BoxShape{size};
    scene.real_objects.push_back(room);
    return scene;
}

// A closed box whose walls (seen from inside: the faces' back sides) all emit Le with rho = 0.95.
// Inside a closed box the point form factors from any point sum to 1, so the exact solution is
// uniform: L = Le / (1 - rho) = 20 Le. The faces' normals point outwards, so the room is modelled
// as its inward copy: each face flipped.
TEST(Radiosity, FurnaceClosedRoomConvergesToLeOverOneMinusRho) {
    Scene scene = boxRoom(Vector3d(3.0, 2.0, 2.5));
    std::vector<Face> faces = *realFaces(scene);
    for (Face& f : faces) {  // inward: swap the edges, which flips the normal
        std::swap(f.edge_s, f.edge_t);
        f.normal = -f.normal;
    }
    RadiosityOptions options;
    options.link_epsilon = 0.002;
    options.min_element_size = 0.1;
    options.min_link_size = 0.1;
    options.residual = 1e-7;
    options.max_iterations = 5000;
    auto rays = *RayScene::build(faces, {}, {});
    Radiosity radiosity(faces, {}, {}, *rays, options);
    radiosity.subdivideTo(0.5, 1.0);
    // Every wall emits the same: sources need no splitting for their radiance's sake.
    radiosity.setSourceRadiance(std::vector<double>(radiosity.hierarchy().elements().size(), 1.0));
    radiosity.buildRealLinks();
    const std::size_t n = radiosity.hierarchy().elements().size();
    const double rho = 0.95;
    const Vector3d le(1.0, 2.0, 0.5);
    std::vector<Vector3d> rho_v(n, Vector3d::Constant(rho)), emission(n, le), direct(n, Vector3d::Zero());
    const Solution solution = radiosity.solve(Mode::kReal, rho_v, emission, direct);
    ASSERT_TRUE(solution.summary.converged) << solution.summary.residual;
    double worst = 0.0;
    for (int e : radiosity.leaves(Mode::kReal)) {
        const Vector3d expected = le / (1.0 - rho);
        worst = std::max(worst, ((solution.radiance[static_cast<std::size_t>(e)] - expected).cwiseQuotient(expected)).cwiseAbs().maxCoeff());
    }
    // The form factors of each leaf sum to 1 within the receiver quadrature's error (order 8 at
    // adjacent elements, 1e-3); 1/(1 - rho) = 20 amplifies that to about 2%.
    EXPECT_LT(worst, 0.02) << "leaves " << radiosity.hierarchy().leafCount() << " links " << radiosity.linkCount(Mode::kReal);
    RecordProperty("furnace_worst_relative_error", std::to_string(worst));
    RecordProperty("iterations", solution.summary.iterations);
}

}  // namespace
}  // namespace commonlight::lighting
