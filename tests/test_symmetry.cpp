// A model's self-symmetries (core/symmetry), found when it is prepared: on shapes whose symmetries are known.
#include <gtest/gtest.h>

#include "partloc/core/localize.hpp"
#include "partloc/core/symmetry.hpp"
#include "partloc/sim/shapes.hpp"

using namespace partloc;

namespace {

PreparedModel prepared(const open3d::geometry::TriangleMesh& mesh) {
    return prepare_model("M", &mesh, nullptr, 0.5, 3.0);
}

PreparedModel block(std::vector<double> x, std::vector<double> y, std::vector<double> top) {
    sim::HeightField hf;
    hf.x_edges = std::move(x);
    hf.y_edges = std::move(y);
    hf.top = std::move(top);
    return prepared(*sim::make_height_field_block(hf));
}

// The turn's axis (up to sign) and angle in degrees (0..180).
std::pair<Eigen::Vector3d, double> axis_angle(const Eigen::Isometry3d& T) {
    const Eigen::AngleAxisd aa(T.linear());
    Eigen::Vector3d a = aa.axis();
    double deg = aa.angle() * 180.0 / M_PI;
    if (deg > 180.0) deg = 360.0 - deg;
    return {a, deg};
}

bool has_turn(const Symmetry& s, const Eigen::Vector3d& axis, double deg) {
    for (const auto& t : s.turns) {
        const auto [a, d] = axis_angle(t);
        if (std::abs(std::abs(a.dot(axis)) - 1.0) < 1e-3 && std::abs(d - deg) < 0.5) return true;
    }
    return false;
}

}  // namespace

TEST(Symmetry, AStepBlockOfNoSymmetryHasNone) {
    const PreparedModel m = block({0, 22, 41, 60}, {0, 17, 40}, {30, 30, 30, 30, 12, 21});
    EXPECT_FALSE(m.symmetry.any()) << m.symmetry.sentence();
}

TEST(Symmetry, ABoxMapsOntoItselfByAHalfTurnAboutEachOfItsAxes) {
    const PreparedModel m = block({0, 60}, {0, 30}, {20});
    const Symmetry& s = m.symmetry;
    EXPECT_FALSE(s.revolution);
    EXPECT_FALSE(s.sphere);
    EXPECT_EQ(s.turns.size(), 3u) << s.sentence();
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(has_turn(s, Eigen::Vector3d::Unit(k), 180.0)) << s.sentence();
    // The centre that the turns keep in place, not the samples' mean (a fraction of a spacing off).
    EXPECT_LT((s.centre - Eigen::Vector3d(30, 15, 10)).norm(), 0.02);
    EXPECT_NE(s.sentence().find(", through (30, 15, 10)"), std::string::npos) << s.sentence();
}

TEST(Symmetry, ASquareBlockHasTheQuarterTurnsOfItsSquare) {
    const PreparedModel m = block({0, 40}, {0, 40}, {20});
    const Symmetry& s = m.symmetry;
    // The square's quarter turns and half turn about z, and four flips about horizontal axes: 7 besides 1.
    EXPECT_EQ(s.turns.size(), 7u) << s.sentence();
    EXPECT_TRUE(has_turn(s, Eigen::Vector3d::UnitZ(), 90.0));
    EXPECT_TRUE(has_turn(s, Eigen::Vector3d(1, 1, 0).normalized(), 180.0)) << s.sentence();
    EXPECT_NE(s.sentence().find("90 deg about (0, 0, 1)"), std::string::npos) << s.sentence();
}

TEST(Symmetry, ABlockSteppedAlikeAtBothEndsHasOneHalfTurn) {
    const PreparedModel m = block({0, 15, 45, 60}, {0, 30}, {20, 30, 20});
    const Symmetry& s = m.symmetry;
    ASSERT_EQ(s.turns.size(), 1u) << s.sentence();
    EXPECT_TRUE(has_turn(s, Eigen::Vector3d::UnitZ(), 180.0));
}

TEST(Symmetry, ABlockThatDiffersByAStepAtOneEndIsNotCalledSymmetric) {
    // As the last block, but a 1 mm step 3 mm wide at one end: about 2 % of its surface differs.
    const PreparedModel m = block({0, 15, 45, 57, 60}, {0, 30}, {20, 30, 20, 21});
    EXPECT_FALSE(m.symmetry.any()) << m.symmetry.sentence();
    // The half turn about the base's centre maps all but the step's end onto the block.
    const Eigen::Isometry3d half = rotation_about_line({30, 15, 0}, Eigen::Vector3d::UnitZ(), 180.0);
    const double on = fraction_on_itself(m.dense, half);
    EXPECT_GT(on, 0.9);  // near: what the threshold must tell apart
    EXPECT_LT(on, SymmetrySettings{}.min_on);
}

TEST(Symmetry, ACylinderSpinsFreelyAndFlipsEndForEnd) {
    auto mesh = open3d::geometry::TriangleMesh::CreateCylinder(15.0, 40.0, 96, 4);
    mesh->ComputeTriangleNormals();
    const Symmetry& s = prepared(*mesh).symmetry;
    EXPECT_TRUE(s.revolution) << s.sentence();
    EXPECT_FALSE(s.sphere);
    EXPECT_GT(std::abs(s.axis.z()), 0.999);
    EXPECT_FALSE(s.turns.empty());  // the flip end for end
    for (const auto& t : s.turns) EXPECT_LT((t.linear() * s.axis + s.axis).norm(), 0.01);
    EXPECT_NE(s.sentence().find("spins freely"), std::string::npos) << s.sentence();
}

TEST(Symmetry, ASphereTurnsAnyWay) {
    auto mesh = open3d::geometry::TriangleMesh::CreateSphere(20.0, 60);
    mesh->ComputeTriangleNormals();
    const Symmetry& s = prepared(*mesh).symmetry;
    EXPECT_TRUE(s.sphere) << s.sentence();
    EXPECT_LT(s.centre.norm(), 0.2);
}

TEST(Symmetry, ModelsPlacedTogetherShareATurnOnlyWhereEachMapsOntoItselfByIt) {
    const PreparedModel box = block({0, 60}, {0, 30}, {20});
    const PreparedModel odd = block({0, 22, 41, 60}, {0, 17, 40}, {30, 30, 30, 30, 12, 21});
    const auto at = [](double x, double y, double yaw) {
        return rotation_about_line({x, y, 0}, Eigen::Vector3d::UnitZ(), yaw) * Eigen::Translation3d(x, y, 0);
    };
    Eigen::Isometry3d turn;
    std::size_t source = 9;
    // One box: its own half turns.
    ASSERT_TRUE(common_symmetry({{&box.dense, &box.symmetry, at(0, 0, 10)}}, &turn, &source));
    EXPECT_EQ(source, 0u);
    // Two boxes side by side along their long axes: the half turn about the line through both centres (the
    // boxes' x axes, in line) maps both onto themselves.
    EXPECT_TRUE(common_symmetry(
        {{&box.dense, &box.symmetry, at(0, 0, 0)}, {&box.dense, &box.symmetry, at(100, 0, 0)}}, &turn,
        &source));
    EXPECT_NEAR(std::abs((turn.linear() * Eigen::Vector3d::UnitX()).x()), 1.0, 1e-6);
    // Two boxes turned apart: none.
    EXPECT_FALSE(common_symmetry(
        {{&box.dense, &box.symmetry, at(0, 0, 0)}, {&box.dense, &box.symmetry, at(100, 40, 30)}}, &turn,
        &source));
    // A box with a block of no symmetry: none.
    EXPECT_FALSE(common_symmetry(
        {{&box.dense, &box.symmetry, at(0, 0, 0)}, {&odd.dense, &odd.symmetry, at(100, 0, 0)}}, &turn,
        &source));
}
