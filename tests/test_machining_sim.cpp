// The allowance map of the whole pipeline on simulated cells, against the stock the simulator made: at
// every scanned sample of the final part, where it was located, the true allowance is the distance along
// the sample's normal to the simulated workpiece's surface (Embree, on its exact mesh). Issue 26: "a test
// of the sim's allowance against its known layout".
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "partloc/pipeline/run.hpp"
#include "partloc/sim/scanner.hpp"
#include "partloc/sim/scenario.hpp"

namespace partloc {
namespace {

/// The true allowance at p along the outward unit normal n: + where p lies inside the stock (the distance
/// out to its surface), - where p lies outside it; NaN when no surface lies either way.
double true_allowance(const sim::RayScene& scene, const std::vector<Eigen::Vector3d>& V,
                      const open3d::geometry::TriangleMesh& mesh, const Eigen::Vector3d& p,
                      const Eigen::Vector3d& n) {
    const auto outward = [&](const sim::RayScene::Hit& h) {
        const auto& t = mesh.triangles_[h.triangle];
        return (V[t(1)] - V[t(0)]).cross(V[t(2)] - V[t(0)]).normalized();
    };
    double best = std::numeric_limits<double>::quiet_NaN();
    const sim::RayScene::Hit out = scene.intersect(p, n);
    if (std::isfinite(out.range) && outward(out).dot(n) > 0) best = out.range;  // leaving the material
    const sim::RayScene::Hit in = scene.intersect(p, -n);
    if (std::isfinite(in.range) && outward(in).dot(n) > 0 && !(std::abs(best) <= in.range))
        best = -in.range;  // the material begins behind p
    return best;
}

struct Outcome {
    std::size_t scanned = 0, compared = 0, within = 0;
    std::size_t over = 0;   ///< read more stock than there is by > 0.1 mm: a silent break-out
    std::size_t under = 0;  ///< read less by > 0.1 mm: a false alarm
    double worst_over = 0.0, worst_under = 0.0;
    std::string describe() const {
        std::ostringstream s;
        s << compared << " of " << scanned << " scanned samples compared, " << within << " within 0.05 mm, "
          << over << " over by > 0.1 (worst " << worst_over << "), " << under << " under by > 0.1 (worst "
          << worst_under << ")";
        return s.str();
    }
};

Outcome compare(const sim::SimulatedJob& s, const MachiningResult& m) {
    const int w = s.cell.find("workpiece");
    EXPECT_GE(w, 0);
    sim::Cell stock_only;
    stock_only.machine = s.cell.machine;
    stock_only.bodies = {s.cell.bodies[w]};
    const sim::RayScene scene(stock_only, AxisValues{});
    const auto& body = stock_only.bodies[0];
    const Eigen::Isometry3d T = stock_only.T_machine_body(body, AxisValues{});
    std::vector<Eigen::Vector3d> V;
    for (const auto& v : body.mesh->vertices_) V.push_back(T * v);
    Outcome o;
    const AllowanceMap& map = m.located;
    for (std::size_t i = 0; i < map.points.size(); ++i) {
        if (std::isnan(map.allowance[i])) continue;
        ++o.scanned;
        const double truth = true_allowance(scene, V, *body.mesh, map.points[i], map.normals[i]);
        if (!std::isfinite(truth) || std::abs(truth) > 5.0) continue;
        ++o.compared;
        const double e = map.allowance[i] - truth;
        if (std::abs(e) <= 0.05) ++o.within;
        if (e > 0.1) ++o.over;
        if (e < -0.1) ++o.under;
        o.worst_over = std::max(o.worst_over, e);
        o.worst_under = std::min(o.worst_under, e);
    }
    return o;
}

class SimulatedAllowance : public ::testing::TestWithParam<int> {};

TEST_P(SimulatedAllowance, MatchesTheSimulatedStock) {
    const sim::SimulatedJob s = sim::simulate_random_cell(static_cast<std::uint64_t>(GetParam()));
    ASSERT_TRUE(s.job.workpiece.final_part && s.job.workpiece.final_part->mesh);
    RunSettings settings;
    settings.threads = 2;
    settings.build_stock = false;
    const JobResult r = run_job(s.job, settings);
    ASSERT_TRUE(r.workpiece.valid) << r.workpiece.reason;
    ASSERT_TRUE(r.machining.available) << r.machining.reason;
    const Outcome o = compare(s, r.machining);
    ASSERT_GT(o.compared, 1000u) << o.describe();
    const double n = static_cast<double>(o.compared);
    // Over cells 1-40 at 0.13 mm noise (39 located; measured at this commit): 3,067,291 of 3,067,305 scanned
    // samples within 0.05 mm; 14 read more stock than there is by > 0.1 mm, none less. Before it: 1,034
    // and 20 (the levels of low steps mixed in one plane, a neighbouring level carried under one shadowed
    // by its riser), with 4 % more samples scanned.
    EXPECT_GE(static_cast<double>(o.within), 0.999 * n) << o.describe();
    EXPECT_LE(static_cast<double>(o.over), 2e-4 * n) << o.describe();
    EXPECT_LE(static_cast<double>(o.under), 2e-4 * n) << o.describe();
}

// 106: a 0.5 mm step beside a datum face; 28 and 36: lower levels shadowed by their risers (592 and 240
// samples over before).
INSTANTIATE_TEST_SUITE_P(Seeds, SimulatedAllowance, ::testing::Values(106, 28, 36));

}  // namespace
}  // namespace partloc
