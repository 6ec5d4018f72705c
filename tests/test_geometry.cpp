#include <gtest/gtest.h>

#include <random>

#include "partloc/core/geometry.hpp"
#include "partloc/core/kinematics.hpp"

using namespace partloc;

TEST(Geometry, EulerRoundTripOverManySamples) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-179.0, 179.0), v(-89.0, 89.0);
    for (int i = 0; i < 1000; ++i) {
        const Eigen::Vector3d e(u(rng), v(rng), u(rng));
        const Eigen::Matrix3d R = rotation_from_euler_xyz_deg(e);
        EXPECT_NEAR((euler_xyz_deg(R) - e).norm(), 0.0, 1e-9);
        EXPECT_NEAR((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    }
}

TEST(Geometry, EulerMeansXThenYThenZAboutMachineAxes) {
    // Rx(90) takes Y to Z; then Rz(90) takes Z to Z: so Y -> Z.  X: Rx leaves X, Rz(90) takes X to Y.
    const Eigen::Matrix3d R = rotation_from_euler_xyz_deg({90, 0, 90});
    EXPECT_NEAR((R * Eigen::Vector3d::UnitY() - Eigen::Vector3d::UnitZ()).norm(), 0, 1e-12);
    EXPECT_NEAR((R * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 0, 1e-12);
}

TEST(Geometry, CheckedIsometryRejectsNonRigid) {
    Eigen::Matrix4d M = Eigen::Matrix4d::Identity();
    EXPECT_NO_THROW(checked_isometry(M, "pose"));
    M(0, 0) = 2;
    EXPECT_THROW(checked_isometry(M, "pose"), std::invalid_argument);
    M = Eigen::Matrix4d::Identity();
    M(2, 2) = -1;  // a mirror
    EXPECT_THROW(checked_isometry(M, "pose"), std::invalid_argument);
}

TEST(Kinematics, RotaryAxisTurnsAboutItsLine) {
    Machine m;
    m.axes.push_back({"A", AxisType::Rotary, Eigen::Vector3d::UnitX(), Eigen::Vector3d(0, 10, 0)});
    const Eigen::Isometry3d M = m.motion({"A"}, {{"A", 90.0}});
    // A point on the line stays; (0, 10, 5) turns about X through (0,10,0) to (0, 5, 0).
    EXPECT_NEAR((M * Eigen::Vector3d(3, 10, 0) - Eigen::Vector3d(3, 10, 0)).norm(), 0, 1e-12);
    EXPECT_NEAR((M * Eigen::Vector3d(0, 10, 5) - Eigen::Vector3d(0, 5, 0)).norm(), 0, 1e-12);
    EXPECT_THROW(m.motion({"B"}, {}), std::invalid_argument);
}

TEST(Geometry, LeastShareIsTheWeakestDirectionsShareInAnyFrameAndUnit) {
    std::mt19937 rng(4);
    std::normal_distribution<double> g(0.0, 1.0);
    // Random rows J: the part holds the first five coordinates, not the sixth; the rest of the points hold
    // only the sixth.
    Matrix6d part = Matrix6d::Zero();
    for (int i = 0; i < 200; ++i) {
        Vector6d j;
        for (int k = 0; k < 5; ++k) j[k] = g(rng);
        j[5] = 0.0;
        part += j * j.transpose();
    }
    Matrix6d extra = Matrix6d::Zero();
    extra(5, 5) = 9.0 * part.trace() / 5.0;  // the rest hold only the sixth
    Matrix6d part6 = part;
    part6(5, 5) = extra(5, 5) / 9.0;
    EXPECT_NEAR(least_share(part, part + extra), 0.0, 1e-9);  // the sixth held by none of the part
    const double mu = least_share(part6, part6 + extra);
    EXPECT_NEAR(mu, 0.1, 1e-9);  // e / 9 of the sixth's e / 9 + e
    EXPECT_NEAR(least_share(part6, part6), 1.0, 1e-9);
    // Another frame and unit: information transforms as A^T H A for any invertible change of twist A.
    Matrix6d A;
    for (int r = 0; r < 6; ++r)
        for (int c = 0; c < 6; ++c) A(r, c) = g(rng) * (c < 3 ? 1000.0 : 1.0);
    EXPECT_NEAR(least_share(A.transpose() * part6 * A, A.transpose() * (part6 + extra) * A), mu, 1e-6);
    EXPECT_EQ(least_share(part, part), 0.0);  // the sixth held by nothing at all: no share
}
