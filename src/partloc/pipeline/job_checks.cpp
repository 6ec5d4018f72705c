#include "partloc/pipeline/job_checks.hpp"

#include <algorithm>
#include <cmath>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/format.hpp"

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

}  // namespace partloc
