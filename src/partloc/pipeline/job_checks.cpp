#include "partloc/pipeline/job_checks.hpp"

#include <algorithm>
#include <cmath>
#include <map>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/format.hpp"
#include "partloc/core/median.hpp"
#include "partloc/core/union_find.hpp"

namespace partloc {

std::vector<ScanSummary> summarise_scans(const Job& job, const std::vector<double>* spacings) {
    std::vector<ScanSummary> out;
    for (std::size_t i = 0; i < job.scans.size(); ++i) {
        const Scan& s = job.scans[i];
        ScanSummary m;
        if (s.points && !s.points->points_.empty()) {
            m.points = s.points->points_.size();
            Eigen::AlignedBox3d box;
            for (const auto& p : s.points->points_) box.extend(p);
            m.extent = box.diagonal().norm();
            if (spacings && i < spacings->size())
                m.spacing = (*spacings)[i];
            else if (m.points >= 8)
                m.spacing = measure_cloud(*s.points, 1000).spacing;
        }
        out.push_back(m);
    }
    return out;
}

namespace {

std::string symmetry_warning(const std::string& fiducial, const Symmetry& symmetry) {
    return "fiducial " + fiducial + " cannot place a scan alone: " + symmetry.sentence() +
           " (its own frame); a scan needs another fiducial in view that tells its turns apart";
}

}  // namespace

std::vector<std::string> symmetry_warnings(const Job& job, const std::vector<PreparedModel>& models) {
    std::vector<std::string> out;
    for (std::size_t k = 0; k < models.size() && k < job.fiducials.size(); ++k)
        if (models[k].symmetry.any())
            out.push_back(symmetry_warning(job.fiducials[k].name, models[k].symmetry));
    return out;
}

std::vector<std::string> symmetry_warnings(const Job& job) {
    std::vector<std::string> out;
    for (const Fiducial& f : job.fiducials) {
        const double d = bounding_box(f.model).diagonal().norm();
        if (!(d > 0) || !std::isfinite(d)) continue;
        // Only the surface the symmetry is found on: no PPF table, as prepare_model would build.
        const Symmetry s =
            find_symmetry(model_surface(f.name, f.model.mesh.get(), f.model.points.get(), d / 150.0));
        if (s.any()) out.push_back(symmetry_warning(f.name, s));
    }
    return out;
}

std::vector<std::string> unit_warnings(const Job& job, const std::vector<ScanSummary>& scans,
                                       const UnitCheckSettings& settings) {
    std::vector<double> sizes;
    for (const Fiducial& f : job.fiducials) {
        const double d = bounding_box(f.model).diagonal().norm();
        if (d > 0 && std::isfinite(d)) sizes.push_back(d);
    }
    std::vector<std::string> out;
    if (sizes.empty()) return out;
    std::nth_element(sizes.begin(), sizes.begin() + static_cast<std::ptrdiff_t>(sizes.size() / 2),
                     sizes.end());
    const double F = sizes[sizes.size() / 2];
    const double job_mm = millimetres_per_unit(job.units);
    const auto plausible = [&](const ScanSummary& s, double k) {  // k: the scan's lengths scaled by k
        return s.extent * k >= settings.min_extent * F && s.extent * k <= settings.max_extent * F &&
               (s.spacing <= 0 || s.spacing * k <= settings.max_spacing * F);
    };
    const char* units[] = {"mm", "cm", "m", "in", "um"};
    for (std::size_t i = 0; i < scans.size() && i < job.scans.size(); ++i) {
        const ScanSummary& s = scans[i];
        if (s.points < 8 || !(s.extent > 0) || plausible(s, 1.0)) continue;
        // The unit that makes the scan's span closest to ten fiducials, among those that make it plausible.
        std::string best;
        double best_distance = 1e300, best_k = 1.0;
        for (const char* u : units) {
            const double k = millimetres_per_unit(u) / job_mm;
            if (!plausible(s, k)) continue;
            const double distance = std::abs(std::log(s.extent * k / (10.0 * F)));
            if (distance < best_distance) {
                best_distance = distance;
                best = u;
                best_k = k;
            }
        }
        std::string w = format(
            "%s: its points span %.3g %s, %.3g apart, against fiducials of %.3g %s: not "
            "plausible in %s",
            job.scans[i].file.c_str(), s.extent, job.units.c_str(), s.spacing, job.units.c_str(), F,
            job.units.c_str(), job.units.c_str());
        if (!best.empty())
            w += format("; did you mean units: %s for the scans (they would span %.3g %s)?", best.c_str(),
                        s.extent * best_k, job.units.c_str());
        else
            w += "; are the scans and the models in the units the job says?";
        out.push_back(w);
    }
    return out;
}

std::vector<std::string> reference_offset_warnings(const std::vector<Eigen::Vector3d>& points,
                                                   const std::vector<Eigen::Vector3d>& normals,
                                                   const Surface& reference,
                                                   const Eigen::Isometry3d& T_located_nominal, double noise,
                                                   double spacing, const std::string& units,
                                                   const ReferenceCheckSettings& settings) {
    std::vector<std::string> out;
    const int n = static_cast<int>(reference.points.size());
    if (n == 0 || normals.size() != points.size() || reference.normals.size() != reference.points.size() ||
        !(reference.spacing > 0))
        return out;
    constexpr double kPi = 3.14159265358979323846;
    const double cos_face = std::cos(settings.face_angle_deg * kPi / 180.0);
    // The reference samples' faces: neighbours within 2.5 spacings whose normals agree, joined.
    std::vector<int> parent(n);
    for (int i = 0; i < n; ++i) parent[i] = i;
    int idx[SampleGrid::kMaxK];
    double d2[SampleGrid::kMaxK];
    for (int i = 0; i < n; ++i) {
        const int k = reference.nearest(reference.points[i], 12, 2.5 * reference.spacing, idx, d2);
        for (int j = 0; j < k; ++j)
            if (reference.normals[idx[j]].dot(reference.normals[i]) >= cos_face)
                parent[find_root(parent, idx[j])] = find_root(parent, i);
    }
    std::vector<int> face(n);
    for (int i = 0; i < n; ++i) face[i] = find_root(parent, i);
    // Each scan point near a face: its signed distance along the face's normal (+: outside the reference).
    const double band = settings.band_spacings * std::max(noise, spacing);
    const double beside = 2.0 * reference.spacing;
    const Eigen::Isometry3d T_nominal_located = T_located_nominal.inverse();
    std::map<int, std::vector<double>> offsets;
    for (std::size_t p = 0; p < points.size(); ++p) {
        const Eigen::Vector3d q = T_nominal_located * points[p];
        const Eigen::Vector3d m = T_nominal_located.linear() * normals[p];
        double s2 = 0.0;
        const int k = reference.nearest(q, &s2, std::hypot(band, beside));
        if (k < 0) continue;
        const Eigen::Vector3d& nk = reference.normals[k];
        const Eigen::Vector3d d = q - reference.points[k];
        const double along = nk.dot(d);
        if (std::abs(along) > band || (d - along * nk).norm() > beside || m.dot(nk) < cos_face) continue;
        offsets[face[k]].push_back(along);
    }
    std::map<int, std::pair<Eigen::Vector3d, int>> centres;  // each face's samples' centre, to name it by
    for (int i = 0; i < n; ++i) {
        auto& c = centres.try_emplace(face[i], Eigen::Vector3d::Zero(), 0).first->second;
        c.first += reference.points[i];
        ++c.second;
    }
    for (auto& [f, v] : offsets) {
        if (static_cast<double>(v.size()) < settings.min_points) continue;
        const double mid = median_of(v);
        std::vector<double> dev;
        dev.reserve(v.size());
        for (double x : v) dev.push_back(std::abs(x - mid));
        const double sigma = 1.4826 * median_of(dev);
        if (std::abs(mid) <= settings.offset_noises * noise || sigma > settings.sheet_noises * noise)
            continue;
        const Eigen::Vector3d nn = T_located_nominal.linear() * reference.normals[f];
        const Eigen::Vector3d at = T_located_nominal * (centres[f].first / centres[f].second);
        out.push_back(
            format("the scans lie %.3g %s %s the reference face at [%.3f, %.3f, %.3f] (normal "
                   "[%.2f, %.2f, %.2f]), parallel to it, over %zu points: are the reference surfaces "
                   "the as-built faces? (The finished part's faces are not.)",
                   std::abs(mid), units.c_str(), mid > 0 ? "outside" : "inside", at.x(), at.y(), at.z(),
                   nn.x(), nn.y(), nn.z(), v.size()));
    }
    return out;
}

std::string TurnedScan::sentence() const {
    return format(
        "its part lies turned %.1f degrees about axis %s from the part the other scans locate: at %s = %.1f "
        "it lies on it (%zu of its sampled points on the reference surfaces, against %zu at %s = %.1f as the "
        "job gives); were its axis values left out of the job or mistyped (axes: {%s: %.1f})? Left out of "
        "the part",
        agrees - stated, axis.c_str(), axis.c_str(), agrees, points_agree, points_stated, axis.c_str(),
        stated, axis.c_str(), agrees);
}

std::vector<TurnedScan> turned_scans(const Job& job,
                                     const std::vector<const Eigen::Isometry3d*>& T_machine_scan,
                                     const Surface& reference, const Eigen::Isometry3d& T_located_nominal,
                                     double noise, const AxisCheckSettings& settings) {
    std::vector<TurnedScan> out;
    const auto& chain = job.workpiece.moves_with;
    std::vector<const Axis*> rotary;
    for (const std::string& name : chain)
        if (const Axis* a = job.machine.find(name); a && a->type == AxisType::Rotary) rotary.push_back(a);
    if (rotary.empty() || reference.points.empty()) return out;
    const Eigen::Isometry3d T_nominal_located = T_located_nominal.inverse();
    const double band = settings.band_noises * noise;
    // How far the reference surfaces reach from each axis: a turn of t radians moves them at most r t.
    const auto reach_from = [&](const Axis& a) {
        double r = 0.0;
        for (const auto& p : reference.points) {
            const Eigen::Vector3d m = T_located_nominal * p - a.point;
            r = std::max(r, (m - m.dot(a.direction) * a.direction).norm());
        }
        return r;
    };
    for (std::size_t i = 0; i < job.scans.size() && i < T_machine_scan.size(); ++i) {
        if (!T_machine_scan[i] || !job.scans[i].points) continue;
        const auto& all = job.scans[i].points->points_;
        const std::size_t stride = std::max<std::size_t>(1, all.size() / settings.points);
        std::vector<Eigen::Vector3d> pts;  // machine frame, at the scan's axis values
        for (std::size_t k = 0; k < all.size(); k += stride)
            if (all[k].allFinite()) pts.push_back(*T_machine_scan[i] * all[k]);
        const AxisValues& stated = job.scans[i].axes;
        // The sampled points on the reference surfaces (within `tolerance` of them along their normal) when
        // the scan was taken at `q`.
        const auto on_reference = [&](const AxisValues& q, double tolerance) {
            const Eigen::Isometry3d to_nominal = T_nominal_located * job.machine.motion(chain, q).inverse();
            const double reach = tolerance + 1.5 * reference.spacing;
            std::size_t n = 0;
            for (const auto& p : pts) {
                const Eigen::Vector3d q0 = to_nominal * p;
                double d2 = 0.0;
                const int k = reference.nearest(q0, &d2, reach);
                n += k >= 0 && std::abs(reference.normals[k].dot(q0 - reference.points[k])) < tolerance;
            }
            return n;
        };
        const std::size_t at_stated = on_reference(stated, band);
        TurnedScan best;
        for (const Axis* a : rotary) {
            const double r = reach_from(*a);
            const auto it = stated.find(a->name);
            const double given = it == stated.end() ? 0.0 : it->second;
            AxisValues q = stated;
            // Every `step` degrees over the turn, then finer about the best, each with a tolerance of the
            // motion half a step makes at the surfaces' reach (at least the band).
            double centre = given, span = 180.0;
            for (const double step : {2.0, 0.25, 0.05}) {
                const double tolerance = std::max(band, r * 0.5 * step * M_PI / 180.0);
                std::vector<std::pair<double, std::size_t>> counts;
                std::size_t most = 0;
                for (double d = -span; d < span + 1e-9; d += step) {
                    q[a->name] = centre + d;
                    counts.emplace_back(centre + d, on_reference(q, tolerance));
                    most = std::max(most, counts.back().second);
                }
                // The middle of the peak, not its first value: near the axis the count is flat over a turn of
                // about the tolerance over the radius. The run of values within 10 % of the most, about it.
                std::size_t lo = 0;
                while (counts[lo].second != most) ++lo;
                std::size_t hi = lo;
                const double floor = 0.9 * static_cast<double>(most);
                while (lo > 0 && static_cast<double>(counts[lo - 1].second) >= floor) --lo;
                while (hi + 1 < counts.size() && static_cast<double>(counts[hi + 1].second) >= floor) ++hi;
                centre = 0.5 * (counts[lo].first + counts[hi].first);
                span = 2.0 * step;
            }
            q[a->name] = centre;
            const std::size_t at_best = on_reference(q, band);
            double turn = std::remainder(centre - given, 360.0);
            if (std::abs(turn) < settings.min_turn_deg || at_best <= best.points_agree) continue;
            best.scan = i;
            best.axis = a->name;
            best.stated = given;
            best.agrees = given + turn;
            best.points_agree = at_best;
            best.points_stated = at_stated;
        }
        if (best.axis.empty()) continue;
        if (best.points_agree < settings.min_points ||
            static_cast<double>(best.points_agree) < settings.gain * static_cast<double>(best.points_stated) +
                                                         static_cast<double>(settings.min_gain))
            continue;
        out.push_back(best);
    }
    return out;
}

}  // namespace partloc
