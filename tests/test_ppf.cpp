// The global fit's pair features and voting (core/ppf).
#include <gtest/gtest.h>
#include <open3d/geometry/TriangleMesh.h>

#include <cmath>
#include <random>

#include "partloc/core/geometry.hpp"
#include "partloc/core/ppf.hpp"
#include "partloc/core/surface.hpp"

using namespace partloc;

// The angle bins come from a table of cosine slots; they must be exactly the bins of the definition: bin k
// holds the angles [k pi / A, (k + 1) pi / A), i.e. the number of edges cos(k pi / A), k = 1..A-1, that the
// cosine does not exceed. At the edges themselves, at +-1 and around them too.
TEST(PpfFeatures, AngleBinsAreThoseOfTheDefinition) {
    for (int bins : {15, 30, 7}) {
        PpfSettings s;
        s.sampling = 1.0;
        s.angle_bins = bins;
        const PpfFeatures f(s);
        auto reference = [&](double c) {
            int n = 0;
            for (int k = 1; k < bins; ++k) n += c <= std::cos(k * M_PI / bins);
            return n;
        };
        std::vector<double> cs = {-1.0, 1.0, 0.0, -0.0, std::nextafter(1.0, 0.0), std::nextafter(-1.0, 0.0)};
        for (int k = 1; k < bins; ++k) {
            const double e = std::cos(k * M_PI / bins);
            cs.insert(cs.end(), {e, std::nextafter(e, 2.0), std::nextafter(e, -2.0)});
        }
        std::mt19937_64 rng(bins);
        std::uniform_real_distribution<double> u(-1.0, 1.0);
        for (int i = 0; i < 200000; ++i) cs.push_back(u(rng));
        for (double c : cs) ASSERT_EQ(f.angle_bin(c), reference(c)) << "bins " << bins << " cosine " << c;
    }
}

// A block's samples voted for in a scene made of the same samples moved: the best candidate is that pose.
TEST(PpfDetect, FindsAMovedModelAsItsBestCandidate) {
    auto mesh = open3d::geometry::TriangleMesh::CreateBox(60, 40, 25);
    auto step = open3d::geometry::TriangleMesh::CreateBox(20, 40, 15);
    step->Translate(Eigen::Vector3d(0, 0, 25));
    *mesh += *step;
    const auto model = sample_mesh(*mesh, 3.0);
    PpfSettings s;
    s.sampling = 3.0;
    const PpfModel table(model->points_, model->normals_, s);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(0.9, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(100, -40, 30);
    std::vector<Eigen::Vector3d> pts, normals;
    for (std::size_t i = 0; i < model->points_.size(); ++i) {
        pts.push_back(T * model->points_[i]);
        normals.push_back(T.linear() * model->normals_[i]);
    }
    const auto found = ppf_detect(table, pts, normals);
    ASSERT_FALSE(found.empty());
    const PoseError e = pose_error(found.front().T_scene_model, T);
    EXPECT_LT(e.translation, 2.0 * s.sampling);
    EXPECT_LT(e.rotation_deg, 12.0);
}
