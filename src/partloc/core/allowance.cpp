#include "partloc/core/allowance.hpp"

#include <open3d/geometry/TriangleMesh.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <numeric>
#include <stdexcept>
#include <unordered_map>

#include "partloc/core/median.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/core/union_find.hpp"

namespace partloc {

namespace {

constexpr double kPi = 3.14159265358979323846;
const double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Each triangle's face: triangles joined across shared edges (vertices merged by position: an STL repeats
/// them per triangle) whose normals differ by less than `angle_deg`.
std::vector<int> face_of_triangles(const open3d::geometry::TriangleMesh& mesh,
                                   const std::vector<Eigen::Vector3d>& tn, double angle_deg) {
    const std::size_t nt = mesh.triangles_.size();
    std::map<std::array<double, 3>, int> ids;
    std::vector<int> vid(mesh.vertices_.size());
    for (std::size_t v = 0; v < mesh.vertices_.size(); ++v) {
        const Eigen::Vector3d& x = mesh.vertices_[v];
        vid[v] = ids.emplace(std::array<double, 3>{x.x(), x.y(), x.z()}, static_cast<int>(ids.size()))
                     .first->second;
    }
    std::unordered_map<std::uint64_t, std::vector<int>> edges;
    for (std::size_t t = 0; t < nt; ++t)
        for (int e = 0; e < 3; ++e) {
            const auto a = static_cast<std::uint64_t>(vid[mesh.triangles_[t](e)]);
            const auto b = static_cast<std::uint64_t>(vid[mesh.triangles_[t]((e + 1) % 3)]);
            if (a == b) continue;
            edges[std::min(a, b) << 32 | std::max(a, b)].push_back(static_cast<int>(t));
        }
    std::vector<int> parent(nt);
    std::iota(parent.begin(), parent.end(), 0);
    const double cos_max = std::cos(angle_deg * kPi / 180.0);
    for (const auto& [key, tris] : edges)
        for (std::size_t i = 0; i < tris.size(); ++i)
            for (std::size_t j = i + 1; j < tris.size(); ++j)
                if (tn[tris[i]].dot(tn[tris[j]]) >= cos_max)
                    parent[find_root(parent, tris[i])] = find_root(parent, tris[j]);
    std::vector<int> face(nt);
    for (std::size_t t = 0; t < nt; ++t) face[t] = find_root(parent, static_cast<int>(t));
    return face;
}

/// A least-squares plane through `members` (normal on the side of their normals), refitted without the points
/// beyond 2.5 robust sigmas of it (at the stock's edges: points of the next face whose estimated normals
/// still turn this way). No fit (points 0) when fewer than `need` remain.
StockPlaneFit robust_plane(const std::vector<Eigen::Vector3d>& points,
                           const std::vector<Eigen::Vector3d>& normals, std::vector<int>& members,
                           double need, double noise) {
    StockPlaneFit fit;
    Eigen::Vector3d outward = Eigen::Vector3d::Zero();
    for (int j : members) outward += normals[j];
    std::vector<double> residual, sorted;
    for (int pass = 0; pass < 4; ++pass) {
        if (members.size() < std::max(need, 3.0)) return StockPlaneFit{};
        Eigen::Vector3d c = Eigen::Vector3d::Zero();
        for (int j : members) c += points[j];
        c /= static_cast<double>(members.size());
        Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
        for (int j : members) {
            const Eigen::Vector3d d = points[j] - c;
            C += d * d.transpose();
        }
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(C);
        Eigen::Vector3d m = eig.eigenvectors().col(0);
        if (m.dot(outward) < 0) m = -m;
        fit.centre = c;
        fit.normal = m;
        fit.points = members.size();
        for (int k = 0; k < 2; ++k) {
            fit.axis[k] = eig.eigenvectors().col(k + 1);
            fit.spread[k] = eig.eigenvalues()[k + 1];
        }
        residual.clear();
        for (int j : members) residual.push_back(std::abs((points[j] - c).dot(m)));
        sorted = residual;
        std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
        fit.sigma = 1.4826 * sorted[sorted.size() / 2];
        if (pass == 3) break;
        const double band = 2.5 * std::max(fit.sigma, 0.25 * noise);
        std::vector<int> kept;
        for (std::size_t k = 0; k < members.size(); ++k)
            if (residual[k] <= band) kept.push_back(members[k]);
        if (kept.size() == members.size()) break;
        members.swap(kept);
    }
    return fit;
}

/// The plane of the as-built surface that the line p + t n crosses nearest to p (header).
StockPlane plane_near(const ScannedStock& stock, const Eigen::Vector3d& p, const Eigen::Vector3d& n,
                      const AllowanceSettings& s, double reach, std::vector<int>& idx,
                      std::vector<std::pair<double, int>>& cand) {
    StockPlane plane;
    const double R = s.smoothing * s.spacing;
    const double cos_max = std::cos(s.max_normal_angle_deg * kPi / 180.0);
    // The cylinder of radius R about the line, |t| <= reach, as balls along it: ball k (centre p + k R n,
    // radius R sqrt(1.25)) holds every point of the cylinder whose t lies within R / 2 of k R, so each point
    // is taken from one ball only.
    const int K = static_cast<int>(std::ceil(reach / R));
    cand.clear();
    for (int k = -K; k <= K; ++k) {
        stock.grid.within(p + (k * R) * n, R * std::sqrt(1.25), idx, false);
        for (int j : idx) {
            const Eigen::Vector3d d = stock.points[j] - p;
            const double t = d.dot(n);
            if (t < (k - 0.5) * R || t >= (k + 0.5) * R || std::abs(t) > reach) continue;
            if ((d - t * n).squaredNorm() >= R * R) continue;
            if (stock.normals[j].dot(n) < cos_max) continue;
            cand.emplace_back(t, j);
        }
    }
    const double need = s.min_support * kPi * s.smoothing * s.smoothing;
    if (cand.size() < std::max(need, 3.0)) return plane;
    std::sort(cand.begin(), cand.end());
    // Sheets along the line: runs of t without a gap wider than the noise and the spacing allow; the
    // nearest with the support of a plane is the surface the line meets, where it lies on the line: enough
    // of its points within r_in of the line (as many as min_support asks of that smaller disc), and on both
    // sides of it (a fifth of them at least beyond the line from where most lie). Else the line passes by
    // that sheet's edge, and no farther sheet is taken either: a neighbouring level, carried under the line,
    // reads stock where the scans saw none (the lower level of a step shadowed by its riser: 6.5 mm read
    // where 1.0 mm was there; tests/test_machining_sim.cpp). The sample is unscanned.
    const double gap = std::max(4.0 * s.noise, 3.0 * s.spacing);
    std::size_t best_first = 0, best_last = 0;
    double best_distance = std::numeric_limits<double>::infinity();
    for (std::size_t first = 0; first < cand.size();) {
        std::size_t last = first + 1;
        while (last < cand.size() && cand[last].first - cand[last - 1].first <= gap) ++last;
        const double lo = cand[first].first, hi = cand[last - 1].first;
        const double distance = lo <= 0 && hi >= 0 ? 0.0 : std::min(std::abs(lo), std::abs(hi));
        if (static_cast<double>(last - first) >= need && distance < best_distance) {
            best_distance = distance;
            best_first = first;
            best_last = last;
        }
        first = last;
    }
    if (best_last == 0) return plane;
    // The sheet's points on the line (within r_in of it): their offsets from it, their heights along it and
    // their flat regions, for the test here and the region below.
    const double r_in = std::max(2.5 * s.spacing, 0.25 * R);
    std::vector<double> inner;
    std::unordered_map<int, int> inner_votes;
    {
        const double need_in = std::max(3.0, s.min_support * kPi * (r_in / s.spacing) * (r_in / s.spacing));
        const bool regions = stock.region.size() == stock.points.size();
        std::vector<Eigen::Vector3d> lateral;
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (std::size_t i = best_first; i < best_last; ++i) {
            const Eigen::Vector3d d = stock.points[cand[i].second] - p;
            const Eigen::Vector3d l = d - cand[i].first * n;
            if (l.squaredNorm() >= r_in * r_in) continue;
            lateral.push_back(l);
            mean += l;
            inner.push_back(cand[i].first);
            if (regions && stock.region[cand[i].second] >= 0) ++inner_votes[stock.region[cand[i].second]];
        }
        std::size_t beyond = 0;
        for (const auto& l : lateral)
            if (l.dot(mean) <= 0) ++beyond;
        if (static_cast<double>(lateral.size()) < need_in || 5 * beyond < lateral.size()) return plane;
    }
    std::vector<int> members;
    for (std::size_t i = best_first; i < best_last; ++i) members.push_back(cand[i].second);
    StockPlaneFit fit = robust_plane(stock.points, stock.normals, members, need, s.noise);
    if (fit.points == 0 || fit.normal.dot(n) < cos_max) return plane;
    const double floor = 0.25 * s.noise;
    // The flat region of the points nearest the line, where it meets the line where they do. Near a low
    // step (a riser of a millimetre, whose points' estimated normals turn less than max_normal_angle_deg
    // from the levels'), the disc holds both levels and the riser, and its plane tilts between them:
    // seed 106 read +0.28 and -0.30 mm on faces whose stock is the face itself
    // (tests/test_machining_sim.cpp). The points within a few spacings of the line lie on one level, and
    // that level's region plane is exact there.
    {
        int best = -1, most = 0;
        for (const auto& [r, count] : inner_votes)
            if (count > most) {
                best = r;
                most = count;
            }
        if (inner.size() >= 8 && best >= 0 && 3 * most >= 2 * static_cast<int>(inner.size())) {
            const StockPlaneFit& r = stock.regions[best];
            const StockPlane region{true, r.centre, r.normal, static_cast<int>(r.points)};
            const double t_inner = median_of(inner);
            const double a_region = allowance_on_plane(region, p, n);
            const Eigen::Vector3d x = p + a_region * n;
            // The inner points' median height: its standard error from the scanner's noise (1.25 sigma /
            // sqrt(N) for a median), and the region plane's own there.
            const double se = std::hypot(1.2533 * s.noise / std::sqrt(static_cast<double>(inner.size())),
                                         r.height_se(x, floor));
            if (r.points > fit.points && r.normal.dot(n) >= cos_max &&
                r.sigma <= 1.25 * std::max(floor, s.noise) && std::abs(a_region - t_inner) <= 4.0 * se)
                return region;
        }
    }
    // The flat region most of the points belong to, where it is as flat and agrees (ScannedStock::region).
    {
        std::unordered_map<int, int> votes;
        for (int j : members)
            if (stock.region.size() == stock.points.size() && stock.region[j] >= 0) ++votes[stock.region[j]];
        int best = -1, most = 0;
        for (const auto& [r, count] : votes)
            if (count > most) {
                best = r;
                most = count;
            }
        if (best >= 0 && 2 * most >= static_cast<int>(members.size())) {
            const StockPlaneFit& r = stock.regions[best];
            if (r.points > fit.points && r.sigma <= 1.25 * std::max({fit.sigma, floor, s.noise}) &&
                r.normal.dot(n) >= cos_max) {
                const StockPlane narrow{true, fit.centre, fit.normal, static_cast<int>(fit.points)};
                const StockPlane region{true, r.centre, r.normal, static_cast<int>(r.points)};
                const double a_narrow = allowance_on_plane(narrow, p, n);
                const Eigen::Vector3d x = p + a_narrow * n;
                // The narrow plane's scatter at least the scanner's noise: from a hundred points at an edge,
                // trimmed of the next face's, it came out at 0.6 of the noise, with its plane tilted 2.6
                // degrees by them (0.08 mm off where the line met it).
                const double se = std::hypot(fit.height_se(x, s.noise), r.height_se(x, floor));
                if (std::abs(allowance_on_plane(region, p, n) - a_narrow) <= 4.0 * se) return region;
            }
        }
    }
    // Wider, where the surface stays as flat: the points of the same sheet within `smoothing_max` of where
    // the line crosses it. Taken when they scatter as little about their plane and agree with the narrow
    // fit to within its standard error.
    const double R_wide = s.smoothing_max * s.spacing;
    if (R_wide > R) {
        const Eigen::Vector3d x = p + (fit.centre - p).dot(fit.normal) / n.dot(fit.normal) * n;
        // About the plane through x square to the points' mean normal: the narrow plane's own tilt is
        // uncertain where it holds half a disc (at the edge of a scanned patch).
        Eigen::Vector3d mean_normal = Eigen::Vector3d::Zero();
        for (int j : members) mean_normal += stock.normals[j];
        mean_normal.normalize();
        const double band = 3.0 * std::max(fit.sigma, s.noise);
        stock.grid.within(x, R_wide, idx, false);
        std::vector<int> wide;
        for (int j : idx) {
            const Eigen::Vector3d d = stock.points[j] - x;
            if (std::abs(d.dot(mean_normal)) > band || stock.normals[j].dot(n) < cos_max) continue;
            wide.push_back(j);
        }
        StockPlaneFit w = robust_plane(stock.points, stock.normals, wide, need, s.noise);
        // Flat as far (the scatter no larger than the narrow fit's or the scanner's noise) and the same
        // surface (the heights where the line meets them agree within the narrow fit's error there).
        if (w.points > fit.points && w.sigma <= 1.25 * std::max({fit.sigma, floor, s.noise}) &&
            w.normal.dot(n) >= cos_max) {
            StockPlane narrow{true, fit.centre, fit.normal, static_cast<int>(fit.points)};
            StockPlane wider{true, w.centre, w.normal, static_cast<int>(w.points)};
            const double se = std::hypot(fit.height_se(x, floor), w.height_se(x, floor));
            if (std::abs(allowance_on_plane(wider, p, n) - allowance_on_plane(narrow, p, n)) <= 4.0 * se)
                fit = w;
        }
    }
    plane.centre = fit.centre;
    plane.normal = fit.normal;
    plane.points = static_cast<int>(fit.points);
    plane.scanned = true;
    return plane;
}

/// ScannedStock::region (allowance.hpp): planar region growing from each point not yet in a region, the
/// region's plane refitted as it grows by half.
void grow_regions(ScannedStock& stock, const AllowanceSettings& s) {
    const std::size_t n = stock.points.size();
    stock.region.assign(n, -1);
    stock.regions.clear();
    const double radius = 2.5 * s.spacing, band = 3.0 * s.noise;
    const double cos_max = std::cos(s.max_normal_angle_deg * kPi / 180.0);
    const double need = s.min_support * kPi * s.smoothing * s.smoothing;
    std::vector<int> label(n, -1), idx, members;
    int next_label = 0;
    for (std::size_t seed = 0; seed < n; ++seed) {
        if (label[seed] >= 0) continue;
        const int id = next_label++;
        members.assign(1, static_cast<int>(seed));
        label[seed] = id;
        Eigen::Vector3d sum = stock.points[seed], c = stock.points[seed], m = stock.normals[seed];
        Eigen::Matrix3d sum2 = stock.points[seed] * stock.points[seed].transpose();
        std::size_t refit = 16;
        for (std::size_t head = 0; head < members.size(); ++head) {
            stock.grid.within(stock.points[members[head]], radius, idx, false);
            for (int j : idx) {
                if (label[j] >= 0 || stock.normals[j].dot(m) < cos_max ||
                    std::abs((stock.points[j] - c).dot(m)) > band)
                    continue;
                label[j] = id;
                members.push_back(j);
                sum += stock.points[j];
                sum2 += stock.points[j] * stock.points[j].transpose();
                if (members.size() >= refit) {
                    const double k = static_cast<double>(members.size());
                    c = sum / k;
                    const Eigen::Matrix3d C = sum2 / k - c * c.transpose();
                    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(C);
                    const Eigen::Vector3d e = eig.eigenvectors().col(0);
                    m = e.dot(m) < 0 ? Eigen::Vector3d(-e) : e;
                    refit = refit * 3 / 2;
                }
            }
        }
        if (static_cast<double>(members.size()) < 4.0 * need) continue;
        StockPlaneFit fit = robust_plane(stock.points, stock.normals, members, need, s.noise);
        if (fit.points == 0) continue;
        const int r = static_cast<int>(stock.regions.size());
        for (int j : members) stock.region[j] = r;
        stock.regions.push_back(fit);
    }
}

}  // namespace

double StockPlaneFit::height_se(const Eigen::Vector3d& q, double sigma_floor) const {
    const double s = std::max(sigma, sigma_floor);
    double v = 1.0 / static_cast<double>(std::max<std::size_t>(points, 1));
    for (int k = 0; k < 2; ++k) {
        const double d = (q - centre).dot(axis[k]);
        v += d * d / std::max(spread[k], 1e-300);
    }
    return s * std::sqrt(v);
}

PartSamples sample_part(const open3d::geometry::TriangleMesh& mesh, double spacing, double face_angle_deg) {
    if (mesh.triangles_.empty()) throw std::invalid_argument("the final part has no triangles");
    if (!(spacing > 0)) throw std::invalid_argument("the final part's sampling must be > 0");
    std::vector<Eigen::Vector3d> tn(mesh.triangles_.size(), Eigen::Vector3d::Zero());
    std::vector<double> area(mesh.triangles_.size(), 0.0);
    std::vector<Eigen::Vector3d> centroid(mesh.triangles_.size());
    for (std::size_t t = 0; t < mesh.triangles_.size(); ++t) {
        const Eigen::Vector3d& a = mesh.vertices_[mesh.triangles_[t](0)];
        const Eigen::Vector3d& b = mesh.vertices_[mesh.triangles_[t](1)];
        const Eigen::Vector3d& c = mesh.vertices_[mesh.triangles_[t](2)];
        const Eigen::Vector3d cross = (b - a).cross(c - a);
        area[t] = 0.5 * cross.norm();
        if (area[t] > 0) tn[t] = cross.normalized();
        centroid[t] = (a + b + c) / 3.0;
    }
    const std::vector<int> root = face_of_triangles(mesh, tn, face_angle_deg);
    // Faces by decreasing area (ties by their first triangle), numbered from 1.
    std::map<int, PartFace> by_root;
    for (std::size_t t = 0; t < root.size(); ++t) {
        PartFace& f = by_root[root[t]];
        f.area += area[t];
        f.normal += area[t] * tn[t];
        f.centre += area[t] * centroid[t];
    }
    std::vector<std::pair<int, PartFace>> order(by_root.begin(), by_root.end());
    std::stable_sort(order.begin(), order.end(),
                     [](const auto& x, const auto& y) { return x.second.area > y.second.area; });
    PartSamples out;
    std::map<int, int> index_of_root;
    for (auto& [r, f] : order) {
        f.id = static_cast<int>(out.faces.size()) + 1;
        if (f.area > 0) f.centre /= f.area;
        if (f.normal.norm() > 0) f.normal.normalize();
        index_of_root[r] = static_cast<int>(out.faces.size());
        out.faces.push_back(f);
    }
    std::vector<int> tri;
    const auto cloud = sample_mesh(mesh, spacing, &tri);
    out.points = cloud->points_;
    out.normals = cloud->normals_;
    out.face.reserve(tri.size());
    for (int t : tri) out.face.push_back(index_of_root[root[t]]);
    return out;
}

ScannedStock make_scanned_stock(std::vector<Eigen::Vector3d> points, std::vector<Eigen::Vector3d> normals,
                                const AllowanceSettings& settings) {
    if (points.size() != normals.size())
        throw std::invalid_argument("the stock's points need one normal each");
    if (!(settings.spacing > 0)) throw std::invalid_argument("the allowance needs the scanner's spacing");
    const double cell = 0.5 * settings.smoothing * settings.spacing;
    ScannedStock s;
    s.points = std::move(points);
    s.normals = std::move(normals);
    s.grid = RadiusGrid(s.points, cell);
    if (settings.noise > 0) grow_regions(s, settings);
    return s;
}

double allowance_on_plane(const StockPlane& plane, const Eigen::Vector3d& p, const Eigen::Vector3d& n) {
    const double along = n.dot(plane.normal);
    if (!(std::abs(along) > 1e-9)) return kNaN;
    return (plane.centre - p).dot(plane.normal) / along;
}

AllowanceMap measure_allowance(const PartSamples& part, const Eigen::Isometry3d& T, const ScannedStock& stock,
                               const AllowanceSettings& settings) {
    if (!(settings.spacing > 0) || !(settings.noise > 0))
        throw std::invalid_argument("the allowance needs the scanner's spacing and noise");
    AllowanceMap map;
    const std::size_t n = part.points.size();
    map.points.resize(n);
    map.normals.resize(n);
    map.allowance.assign(n, kNaN);
    map.planes.assign(n, StockPlane{});
    Eigen::AlignedBox3d box;
    for (std::size_t i = 0; i < n; ++i) {
        map.points[i] = T * part.points[i];
        map.normals[i] = T.linear() * part.normals[i];
        box.extend(map.points[i]);
    }
    const double reach = settings.reach > 0 ? settings.reach : 0.05 * (n ? box.diagonal().norm() : 0.0);
    if (n && stock.grid.size() && reach > 0)
        tbb::parallel_for(
            tbb::blocked_range<std::size_t>(0, n, 256), [&](const tbb::blocked_range<std::size_t>& r) {
                std::vector<int> idx;
                std::vector<std::pair<double, int>> cand;
                for (std::size_t i = r.begin(); i != r.end(); ++i) {
                    map.planes[i] =
                        plane_near(stock, map.points[i], map.normals[i], settings, reach, idx, cand);
                    if (map.planes[i].scanned)
                        map.allowance[i] = allowance_on_plane(map.planes[i], map.points[i], map.normals[i]);
                }
            });
    summarise_allowance(part, map);
    return map;
}

AllowanceMap allowance_on_planes(const PartSamples& part, const Eigen::Isometry3d& T,
                                 const AllowanceMap& at) {
    AllowanceMap map;
    const std::size_t n = part.points.size();
    map.points.resize(n);
    map.normals.resize(n);
    map.allowance.assign(n, kNaN);
    map.planes = at.planes;
    for (std::size_t i = 0; i < n; ++i) {
        map.points[i] = T * part.points[i];
        map.normals[i] = T.linear() * part.normals[i];
        if (map.planes[i].scanned)
            map.allowance[i] = allowance_on_plane(map.planes[i], map.points[i], map.normals[i]);
    }
    summarise_allowance(part, map);
    return map;
}

void summarise_allowance(const PartSamples& part, AllowanceMap& map) {
    map.faces.assign(part.faces.size(), FaceAllowance{});
    for (std::size_t f = 0; f < part.faces.size(); ++f) map.faces[f].id = part.faces[f].id;
    map.all = FaceAllowance{};
    std::vector<double> sum(part.faces.size(), 0.0);
    double total = 0.0;
    const auto add = [&](FaceAllowance& f, double a, const Eigen::Vector3d& p) {
        ++f.samples;
        if (std::isnan(a)) {
            ++f.unscanned;
            return;
        }
        if (std::isnan(f.min) || a < f.min) {
            f.min = a;
            f.min_at = p;
        }
        if (std::isnan(f.max) || a > f.max) f.max = a;
    };
    for (std::size_t i = 0; i < map.allowance.size(); ++i) {
        const double a = map.allowance[i];
        const int f = part.face[i];
        add(map.faces[f], a, map.points[i]);
        add(map.all, a, map.points[i]);
        if (!std::isnan(a)) {
            sum[f] += a;
            total += a;
        }
    }
    for (std::size_t f = 0; f < map.faces.size(); ++f) {
        const std::size_t scanned = map.faces[f].samples - map.faces[f].unscanned;
        if (scanned) map.faces[f].mean = sum[f] / static_cast<double>(scanned);
    }
    const std::size_t scanned = map.all.samples - map.all.unscanned;
    if (scanned) map.all.mean = total / static_cast<double>(scanned);
    map.min_face = -1;
    for (std::size_t f = 0; f < map.faces.size(); ++f)
        if (!std::isnan(map.faces[f].min) &&
            (map.min_face < 0 || map.faces[f].min < map.faces[map.min_face].min))
            map.min_face = static_cast<int>(f);
}

std::string face_name(const PartFace& face, const Eigen::Matrix3d& R_mesh_frame) {
    std::string name = "face " + std::to_string(face.id);
    const Eigen::Vector3d n = R_mesh_frame.transpose() * face.normal;
    const double cos10 = std::cos(10.0 * kPi / 180.0);
    for (int k = 0; k < 3; ++k)
        if (std::abs(n[k]) >= cos10)
            return name + " (" + (n[k] > 0 ? "+" : "-") + std::string(1, "XYZ"[k]) + ")";
    return name;
}

}  // namespace partloc
