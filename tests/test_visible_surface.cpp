// visible_from_outside (core/visible_surface.hpp): faces inside a solid, as multi-body CAD exports keep
// them, are hidden; every face of a single solid, and of a concave one, is visible.
#include <gtest/gtest.h>
#include <open3d/geometry/TriangleMesh.h>

#include <algorithm>

#include "partloc/core/surface.hpp"
#include "partloc/core/visible_surface.hpp"

using namespace partloc;
using open3d::geometry::TriangleMesh;

namespace {

std::shared_ptr<TriangleMesh> box(double w, double h, double d, const Eigen::Vector3d& at) {
    auto b = TriangleMesh::CreateBox(w, h, d);
    b->Translate(at);
    return b;
}

/// The fraction of the mesh's samples that visible_from_outside calls visible, and of those inside `inner`.
struct Counts {
    std::size_t samples = 0, visible = 0, inside = 0, inside_visible = 0;
};
Counts count(const TriangleMesh& mesh, const Eigen::AlignedBox3d& inner) {
    const auto s = sample_mesh(mesh, 1.0);
    const auto v = visible_from_outside(mesh, s->points_, s->normals_);
    Counts c;
    for (std::size_t i = 0; i < v.size(); ++i) {
        ++c.samples;
        c.visible += v[i];
        if (inner.contains(s->points_[i])) {
            ++c.inside;
            c.inside_visible += v[i];
        }
    }
    return c;
}

TEST(VisibleSurface, EveryFaceOfASolidIsVisible) {
    const auto b = box(40, 30, 20, Eigen::Vector3d::Zero());
    const Counts c = count(*b, Eigen::AlignedBox3d());
    ASSERT_GT(c.samples, 1000u);
    EXPECT_EQ(c.visible, c.samples);
}

TEST(VisibleSurface, TheFloorOfAPocketIsVisible) {
    // A U-shape of three boxes that touch only along lines: the pocket's floor and walls face each other.
    TriangleMesh u = *box(10, 30, 20, {0, 0, 0}) + *box(10, 30, 20, {30, 0, 0}) + *box(20, 30, 5, {10, 0, 0});
    const Counts c =
        count(u, Eigen::AlignedBox3d(Eigen::Vector3d(10.5, 0.5, 5.0), Eigen::Vector3d(29.5, 29.5, 5.0)));
    ASSERT_GT(c.inside, 100u);
    EXPECT_EQ(c.inside_visible, c.inside);  // the floor at z = 5, between the walls
}

TEST(VisibleSurface, FacesInsideOverlappingBodiesAreHidden) {
    // Two boxes overlapping by 10 mm in x, in one mesh: each one's faces inside the other are hidden.
    const TriangleMesh m = *box(40, 30, 20, {0, 0, 0}) + *box(40, 30, 20, {30, 0, 0});
    const Eigen::AlignedBox3d overlap(Eigen::Vector3d(29.9, 0.5, 0.5), Eigen::Vector3d(40.1, 29.5, 19.5));
    const Counts c = count(m, overlap);
    ASSERT_GT(c.inside, 100u);  // the two end faces at x = 30 and x = 40, and the walls' parts between
    EXPECT_EQ(c.inside_visible, 0u);
    EXPECT_GT(c.visible, c.samples / 2);
}

TEST(VisibleSurface, CoincidentFacesOfTouchingBodiesAreHidden) {
    const TriangleMesh m = *box(40, 30, 20, {0, 0, 0}) + *box(40, 30, 20, {0, 0, 20});
    const Counts c =
        count(m, Eigen::AlignedBox3d(Eigen::Vector3d(0.5, 0.5, 19.9), Eigen::Vector3d(39.5, 29.5, 20.1)));
    ASSERT_GT(c.inside, 100u);
    EXPECT_EQ(c.inside_visible, 0u);
}

}  // namespace
