#include "partloc/pipeline/machining.hpp"

#include <chrono>
#include <cmath>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/format.hpp"

namespace partloc {

namespace {

constexpr double kPi = 3.14159265358979323846;

std::string where(const MachiningResult& m, const AllowanceMap& map) {
    const std::string face = map.min_face >= 0 ? " on " + m.face_names[map.min_face] : "";
    return format("at [%.3f, %.3f, %.3f]", map.all.min_at.x(), map.all.min_at.y(), map.all.min_at.z()) + face;
}

}  // namespace

MachiningResult plan_machining(const Job& job, const open3d::geometry::PointCloud& merged,
                               const Eigen::Isometry3d& T_located_nominal,
                               const Eigen::Isometry3d& T_machine_workpiece, double spacing, double noise,
                               MachiningSettings settings) {
    const auto t0 = std::chrono::steady_clock::now();
    MachiningResult m;
    const Workpiece& w = job.workpiece;
    m.required = w.allowance_min.value_or(0.0);
    m.maxmin = w.placement.maxmin;
    if (!w.final_part) return m;
    const auto fail = [&](const std::string& why) {
        m.reason = why;
        m.warnings.push_back("no allowance: " + why);
        return m;
    };
    if (!w.final_part->mesh || w.final_part->mesh->triangles_.empty())
        return fail("the final part " + w.final_part->file +
                    " is points, not a mesh: it has no surface to measure");
    if (merged.points_.size() < 3 || merged.normals_.size() != merged.points_.size())
        return fail("the merged scan points have no normals");
    if (!(spacing > 0) || !(noise > 0)) return fail("the scans' spacing or noise is unknown");

    // The stock the scans show. Its points are thinned (PartSettings::merged_points, the voxels of
    // merged.ply): its own spacing, where coarser than the scans', sets the planes' radii and support.
    const CloudStats stats = measure_cloud(merged);
    AllowanceSettings as = settings.allowance;
    as.spacing = std::max(spacing, stats.spacing);
    as.noise = noise;
    std::vector<Eigen::Vector3d> normals = merged.normals_;
    for (auto& n : normals)
        if (n.norm() > 0) n.normalize();
    const ScannedStock stock = make_scanned_stock(merged.points_, std::move(normals), as);

    const auto& mesh = *w.final_part->mesh;
    m.part = sample_part(mesh, settings.sample_spacings * as.spacing, as.face_angle_deg);
    // Faces named in the datum frame's axes (its rotation in the mesh's, nominal, coordinates).
    for (const PartFace& f : m.part.faces)
        m.face_names.push_back(face_name(f, w.T_machine_workpiece.linear()));
    m.located = measure_allowance(m.part, T_located_nominal, stock, as);
    m.map = m.located;
    m.T_machine_part = T_machine_workpiece;
    if (std::isnan(m.located.all.min)) return fail("no scan saw the stock around the final part");

    if (m.maxmin) {
        PlacementSettings ps = settings.placement;
        ps.free = w.placement.free;
        ps.max_translation = w.placement.max_translation;
        ps.max_rotation_deg = w.placement.max_rotation_deg;
        ps.required = m.required;
        // The iterations on coarser samples; the map at the placement on all of them.
        const auto t_place = std::chrono::steady_clock::now();
        const PartSamples coarse =
            sample_part(mesh, settings.placement_sample_spacings * as.spacing, as.face_angle_deg);
        const AllowanceMap located_coarse = measure_allowance(coarse, T_located_nominal, stock, as);
        const Placement p =
            place_maxmin(coarse, T_located_nominal, T_machine_workpiece, stock, as, ps, located_coarse);
        m.placement_seconds =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t_place).count();
        if (!p.valid) {
            m.placement_reason = p.reason;
            m.warnings.push_back("the placement could not be computed (" + p.reason +
                                 "): the final part is left where it was located");
        } else {
            AllowanceMap placed = measure_allowance(m.part, p.T_move * T_located_nominal, stock, as);
            // Never worse than located, on the full map.
            if (placed.all.min >= m.located.all.min) {
                m.map = std::move(placed);
                m.T_move = p.T_move;
            }
        }
    }
    m.T_machine_part = m.T_move * T_machine_workpiece;
    m.translation = (m.T_machine_part.translation() - T_machine_workpiece.translation()).norm();
    m.rotation_deg = Eigen::AngleAxisd(m.T_move.linear()).angle() * 180.0 / kPi;
    m.fits = m.map.all.min >= m.required;
    auto placed = std::make_shared<open3d::geometry::TriangleMesh>(mesh);
    placed->Transform((m.T_move * T_located_nominal).matrix());
    m.final_part_placed = placed;

    if (!m.fits)
        m.warnings.push_back(
            format("insufficient stock: the least allowance is %.3f %s, where %.3f is required, ",
                   m.map.all.min, job.units.c_str(), m.required) +
            where(m, m.map));
    if (m.map.all.unscanned_fraction() > settings.warn_unscanned_fraction)
        m.warnings.push_back(
            format("%.0f %% of the final part's surface was seen by no scan: its allowance there "
                   "is unknown (allowance.ply marks it unscanned)%s",
                   100.0 * m.map.all.unscanned_fraction(),
                   m.maxmin ? "; the placement could not keep stock there" : ""));
    m.available = true;
    m.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return m;
}

}  // namespace partloc
