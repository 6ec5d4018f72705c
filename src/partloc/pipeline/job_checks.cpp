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

}  // namespace partloc
