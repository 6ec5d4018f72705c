// The same job in micrometres, millimetres, metres and inches (issue 25, item 5): every length of the job
// multiplied by the units' factor must give the same decisions (which scans are registered, by which
// fiducials; located or not) and the same result, scaled. A scale dependence is a defect: the fine fit's
// damping once weighed rotation against translation by the coordinates' size, and a job in micrometres
// registered other scans than the same job in millimetres.
//
// Two strengths. Scaled by a power of two, every product and quotient is exact, so any difference at all
// is a length written into the code: the result must agree to 1e-9 of the part's size. Scaled by the units'
// own factors (1000, 0.001, 1/25.4) every coordinate is rounded, and a fit that ends where its step falls
// below a threshold can end one iteration apart: the decisions must be the same and the result within
// 1e-5 of the part's size (measured: random cell 1320, one scan 0.00035 mm apart of 49 mm in m and in; the
// same difference for a factor of 1 + 3e-16, none for 1 + 1e-12 or 1024).
#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <vector>

#include "partloc/pipeline/run.hpp"
#include "partloc/sim/scenario.hpp"

using namespace partloc;

namespace {

/// A copy of a mesh or a cloud with every coordinate times k (the scale about the origin).
template <typename Geometry>
std::shared_ptr<const Geometry> scaled(const std::shared_ptr<const Geometry>& g, double k) {
    if (!g) return g;
    auto s = std::make_shared<Geometry>(*g);
    s->Scale(k, Eigen::Vector3d::Zero());
    return s;
}

ModelSource scaled(const ModelSource& m, double k) {
    return {m.file, scaled(m.mesh, k), scaled(m.points, k)};
}

Eigen::Isometry3d scaled(Eigen::Isometry3d T, double k) {
    T.translation() *= k;
    return T;
}

AxisValues scaled(AxisValues q, const Machine& machine, double k) {
    for (auto& [name, value] : q)
        if (const Axis* a = machine.find(name); a && a->type == AxisType::Linear) value *= k;
    return q;
}

/// The job with every length multiplied by k, as the same job written in other units would read.
Job scaled(const Job& job, double k, const std::string& units) {
    Job s = job;
    s.units = units;
    if (s.scanner.point_spacing) *s.scanner.point_spacing *= k;
    if (s.scanner.noise) *s.scanner.noise *= k;
    for (Axis& a : s.machine.axes) a.point *= k;
    for (Fiducial& f : s.fiducials) {
        f.model = scaled(f.model, k);
        f.T_machine_fiducial = scaled(f.T_machine_fiducial, k);
        f.probed_at = scaled(f.probed_at, job.machine, k);
        f.pose_sigma *= k;
    }
    Workpiece& w = s.workpiece;
    w.reference_surfaces = scaled(w.reference_surfaces, k);
    w.T_machine_workpiece = scaled(w.T_machine_workpiece, k);
    if (w.final_part) w.final_part = scaled(*w.final_part, k);
    if (w.region) w.region = Eigen::AlignedBox3d(w.region->min() * k, w.region->max() * k);
    for (Datum& d : w.datums) d.surfaces = scaled(d.surfaces, k);
    for (Scan& scan : s.scans) {
        scan.points = scaled(scan.points, k);
        scan.axes = scaled(scan.axes, job.machine, k);
    }
    return s;
}

/// |t_a - t_b| and |R_a^T R_b - I| (about the angle in radians; acos would lose angles below 1e-8).
struct Delta {
    double translation, rotation;
};
Delta delta(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    return {(a.translation() - b.translation()).norm(),
            (a.linear().transpose() * b.linear() - Eigen::Matrix3d::Identity()).norm()};
}

struct Unit {
    const char* name;
    double per_mm;     ///< job units per millimetre
    double tolerance;  ///< of the result, over the part's size
};

/// The powers of two and the units' own factors.
const std::vector<Unit> all_units = {Unit{"mm", 1024.0, 1e-9}, Unit{"mm", 1.0 / 1024.0, 1e-9},
                                     Unit{"um", 1000.0, 1e-5}, Unit{"m", 0.001, 1e-5},
                                     Unit{"in", 1.0 / 25.4, 1e-5}};

void expect_same_in_every_unit(const sim::SimulatedJob& sj, const std::vector<Unit>& units = all_units) {
    RunSettings rs;
    rs.build_stock = false;
    const JobResult mm = run_job(sj.job, rs);
    ASSERT_TRUE(mm.workpiece.valid) << mm.workpiece.reason;
    const double size = bounding_box(sj.job.workpiece.reference_surfaces).diagonal().norm();
    for (const Unit& u : units) {
        SCOPED_TRACE(std::string(u.name) + " x " + std::to_string(u.per_mm));
        const double tol = u.tolerance * size;
        const JobResult r = run_job(scaled(sj.job, u.per_mm, u.name), rs);
        ASSERT_EQ(r.scans.size(), mm.scans.size());
        for (std::size_t i = 0; i < r.scans.size(); ++i) {
            SCOPED_TRACE(r.scans[i].file);
            EXPECT_EQ(r.scans[i].valid, mm.scans[i].valid)
                << r.scans[i].reason << " / " << mm.scans[i].reason;
            EXPECT_EQ(r.scans[i].fiducials, mm.scans[i].fiducials);
            if (!r.scans[i].valid || !mm.scans[i].valid) continue;
            const Delta d =
                delta(scaled(r.scans[i].T_machine_scan, 1.0 / u.per_mm), mm.scans[i].T_machine_scan);
            EXPECT_LT(d.translation, tol);
            EXPECT_LT(d.rotation, u.tolerance);
        }
        ASSERT_EQ(r.workpiece.valid, mm.workpiece.valid) << r.workpiece.reason;
        const Delta d =
            delta(scaled(r.workpiece.T_machine_workpiece, 1.0 / u.per_mm), mm.workpiece.T_machine_workpiece);
        EXPECT_LT(d.translation, tol);
        EXPECT_LT(d.rotation, u.tolerance);
        EXPECT_NEAR(r.workpiece.uncertainty.origin.norm() / u.per_mm, mm.workpiece.uncertainty.origin.norm(),
                    tol);
    }
}

TEST(Units, PaperTestTheSameInEveryUnit) { expect_same_in_every_unit(sim::simulate_paper_test(2, 7)); }

// The powers of two are the paper test's (a length written into the code shows in any job); the random
// cell is run in the units' own factors only, to keep the suite's time.
TEST(Units, RandomCellTheSameInEveryUnit) {
    expect_same_in_every_unit(sim::simulate_random_cell(1320), {all_units.begin() + 2, all_units.end()});
}

}  // namespace
