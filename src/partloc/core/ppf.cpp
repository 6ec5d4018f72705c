#include "partloc/core/ppf.hpp"

#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/PointCloud.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "partloc/core/geometry.hpp"

namespace partloc {

namespace {
constexpr double kTwoPi = 2.0 * M_PI;

double angle_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return std::atan2(a.cross(b).norm(), a.dot(b));
}

// Angle of the second point about +x once the pair is aligned by ppf_align_to_x of the first.
double pair_alpha(const Eigen::Isometry3d& T_g, const Eigen::Vector3d& p2) {
    const Eigen::Vector3d v = T_g * p2;
    return std::atan2(v.z(), v.y());
}
}  // namespace

Eigen::Isometry3d ppf_align_to_x(const Eigen::Vector3d& p, const Eigen::Vector3d& n) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::Quaterniond::FromTwoVectors(n, Eigen::Vector3d::UnitX()).toRotationMatrix();
    T.translation() = -(T.linear() * p);
    return T;
}

PpfModel::PpfModel(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& normals,
                   const PpfSettings& settings)
    : settings_(settings), points_(points), normals_(normals) {
    if (settings_.sampling <= 0) throw std::invalid_argument("PPF sampling must be > 0");
    if (points.size() != normals.size() || points.empty())
        throw std::invalid_argument("PPF model needs points with normals");
    Eigen::AlignedBox3d box;
    for (const auto& p : points_) box.extend(p);
    diameter_ = box.diagonal().norm();
    center_ = box.center();
    distance_bins_ = static_cast<int>(std::ceil(diameter_ / settings_.sampling)) + 2;
    const int nkeys = distance_bins_ * settings_.angle_bins * settings_.angle_bins * settings_.angle_bins;

    // Two passes (count, fill) into CSR arrays: compact and cache friendly.
    const std::size_t n = points_.size();
    std::vector<Eigen::Isometry3d> T_g(n);
    for (std::size_t i = 0; i < n; ++i) T_g[i] = ppf_align_to_x(points_[i], normals_[i]);
    std::vector<int> keys(n * n, -1);
    tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
        for (std::size_t j = 0; j < n; ++j)
            if (i != j) keys[i * n + j] = key(points_[i], normals_[i], points_[j], normals_[j]);
    });
    offsets_.assign(nkeys + 1, 0);
    for (int k : keys)
        if (k >= 0) ++offsets_[k + 1];
    std::partial_sum(offsets_.begin(), offsets_.end(), offsets_.begin());
    entries_.resize(offsets_.back());
    // Features that half the model's pairs share (two perpendicular faces of a block) are shared by every
    // prismatic thing in the cell too: they cost most of the voting and carry little evidence.
    std::size_t used = 0;
    for (int k = 0; k < nkeys; ++k) used += offsets_[k + 1] > offsets_[k];
    max_bucket_ = used ? static_cast<std::size_t>(settings_.bucket_cap * offsets_.back() / used) : 0;
    std::vector<std::uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = 0; j < n; ++j) {
            const int k = keys[i * n + j];
            if (k < 0) continue;
            entries_[fill[k]++] = {static_cast<std::uint32_t>(i),
                                   static_cast<float>(pair_alpha(T_g[i], points_[j]))};
        }
}

int PpfModel::key(const Eigen::Vector3d& p1, const Eigen::Vector3d& n1, const Eigen::Vector3d& p2,
                  const Eigen::Vector3d& n2) const {
    const Eigen::Vector3d d = p2 - p1;
    const double dist = d.norm();
    if (dist < settings_.sampling) return -1;
    const Eigen::Vector3d u = d / dist;
    const double sin_c = std::sin(settings_.coplanar_deg * M_PI / 180.0);
    const double cos_c = std::cos(settings_.coplanar_deg * M_PI / 180.0);
    if (std::abs(n1.dot(n2)) > cos_c && std::abs(u.dot(n1)) < sin_c) return -1;  // one plane: no shape
    const int db = static_cast<int>(dist / settings_.sampling);
    if (db >= distance_bins_) return -1;
    const int A = settings_.angle_bins;
    auto bin = [A](double angle) { return std::min(A - 1, static_cast<int>(angle / M_PI * A)); };
    return ((db * A + bin(angle_between(n1, u))) * A + bin(angle_between(n2, u))) * A + bin(angle_between(n1, n2));
}

std::pair<const PpfModel::Entry*, const PpfModel::Entry*> PpfModel::lookup(int k) const {
    if (k < 0 || k + 1 >= static_cast<int>(offsets_.size())) return {nullptr, nullptr};
    return {entries_.data() + offsets_[k], entries_.data() + offsets_[k + 1]};
}

std::vector<PoseCandidate> ppf_detect(const PpfModel& model, const std::vector<Eigen::Vector3d>& scene_points,
                                      const std::vector<Eigen::Vector3d>& scene_normals) {
    const PpfSettings& s = model.settings();
    if (scene_points.size() < 3) return {};
    open3d::geometry::PointCloud cloud;
    cloud.points_ = scene_points;
    open3d::geometry::KDTreeFlann tree(cloud);

    const int nalpha = s.alpha_bins;
    const std::size_t nm = model.size();
    std::vector<std::size_t> refs;
    // Every k-th point as reference, but at least about a thousand references on a small scene.
    const std::size_t stride =
        std::clamp<std::size_t>(scene_points.size() / 1000, 1, static_cast<std::size_t>(s.reference_stride));
    for (std::size_t r = 0; r < scene_points.size(); r += stride) refs.push_back(r);

    // Each reference point keeps its best pose (Drost §3.3); per-reference slots keep it deterministic.
    std::vector<PoseCandidate> per_ref(refs.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, refs.size(), 16), [&](const auto& range) {
        std::vector<std::uint16_t> acc(nm * nalpha);
        std::vector<int> idx;
        std::vector<double> d2;
        for (std::size_t ri = range.begin(); ri != range.end(); ++ri) {
            const std::size_t r = refs[ri];
            const Eigen::Vector3d& pr = scene_points[r];
            const Eigen::Vector3d& nr = scene_normals[r];
            const Eigen::Isometry3d T_sg = ppf_align_to_x(pr, nr);
            std::fill(acc.begin(), acc.end(), 0);
            tree.SearchRadius(pr, model.diameter(), idx, d2);
            for (int j : idx) {
                if (static_cast<std::size_t>(j) == r) continue;
                const int k = model.key(pr, nr, scene_points[j], scene_normals[j]);
                if (k < 0) continue;
                const auto [b, e] = model.lookup(k);
                if (b == e || static_cast<std::size_t>(e - b) > model.max_bucket()) continue;
                const double alpha_s = pair_alpha(T_sg, scene_points[j]);
                for (const auto* it = b; it != e; ++it) {
                    double a = alpha_s - it->alpha;
                    a -= kTwoPi * std::floor(a / kTwoPi);
                    const int ab = std::min(nalpha - 1, static_cast<int>(a / kTwoPi * nalpha));
                    auto& v = acc[it->model_index * nalpha + ab];
                    if (v < 65535) ++v;
                }
            }
            const auto best = std::max_element(acc.begin(), acc.end());
            if (*best == 0) continue;
            const std::size_t bi = static_cast<std::size_t>(best - acc.begin());
            const std::size_t mi = bi / nalpha;
            const double alpha = (static_cast<double>(bi % nalpha) + 0.5) / nalpha * kTwoPi;
            const Eigen::Isometry3d T_mg = ppf_align_to_x(model.points()[mi], model.normals()[mi]);
            PoseCandidate c;
            c.T_scene_model = T_sg.inverse() * Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitX()) * T_mg;
            c.votes = *best;
            per_ref[ri] = c;
        }
    });

    // Pose clustering (Drost §3.4): greedy, most votes first; a cluster's votes are summed.
    std::vector<PoseCandidate> all;
    for (auto& c : per_ref)
        if (c.votes > 0) all.push_back(c);
    std::stable_sort(all.begin(), all.end(), [](const auto& a, const auto& b) { return a.votes > b.votes; });
    const double dmax = s.cluster_distance > 0 ? s.cluster_distance : 2.0 * s.sampling;
    struct Cluster {
        PoseCandidate rep;
        double votes;
    };
    std::vector<Cluster> clusters;
    for (const auto& c : all) {
        bool joined = false;
        for (auto& cl : clusters) {
            const PoseError e = pose_error(cl.rep.T_scene_model, c.T_scene_model);
            if (e.translation < dmax && e.rotation_deg < s.cluster_rotation_deg) {
                cl.votes += c.votes;
                joined = true;
                break;
            }
        }
        if (!joined) clusters.push_back({c, c.votes});
        if (clusters.size() > 2000) break;
    }
    std::stable_sort(clusters.begin(), clusters.end(), [](const auto& a, const auto& b) { return a.votes > b.votes; });
    // Spread the candidates over the scene: a large structure that resembles the model (a big block with a
    // step) casts many votes for many slightly different poses and would fill the list by itself, crowding
    // out a smaller, partly hidden true instance.
    std::vector<PoseCandidate> out;
    std::vector<Eigen::Vector3d> centres;
    for (const auto& cl : clusters) {
        if (static_cast<int>(out.size()) >= s.max_candidates) break;
        const Eigen::Vector3d c = cl.rep.T_scene_model * model.center();
        int near = 0;
        for (const auto& o : centres) near += (o - c).norm() < 0.25 * model.diameter();
        if (near >= s.per_location) continue;
        centres.push_back(c);
        out.push_back({cl.rep.T_scene_model, cl.votes});
    }
    return out;
}

}  // namespace partloc
