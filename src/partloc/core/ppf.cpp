#include "partloc/core/ppf.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <utility>

#include "partloc/core/geometry.hpp"
#include "partloc/core/sample_grid.hpp"

namespace partloc {

namespace {
constexpr double kTwoPi = 2.0 * M_PI;

// atan2 to about 1e-5 rad, several times cheaper than the library's; the pair angle is binned at 12 degrees,
// and the model's table and the scene use this same function.
double fast_atan2(double y, double x) {
    const double ax = std::abs(x), ay = std::abs(y);
    const double mx = std::max(ax, ay);
    if (mx == 0.0) return 0.0;
    const double a = std::min(ax, ay) / mx;
    const double s = a * a;
    double r =
        ((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s * a +
        0.99997726 * a;
    if (ay > ax) r = M_PI_2 - r;
    if (x < 0) r = M_PI - r;
    return y < 0 ? -r : r;
}

// Angle of the second point about +x once the pair is aligned by ppf_align_to_x of the first, as a fraction
// of a turn in fixed point (2^32 = one turn, [0, 2 pi) in radians).
//
// Fixed point, so that the vote's bin of the difference of a scene and a model angle needs neither a branch
// for the wrap-around nor a float conversion: with the angles in radians, `a < 0 ? a + 2 pi : a` is taken
// at random, and the voting loop ran at 5.4 ns per vote (seed 106, 0.62 billion votes, perf).
std::uint32_t pair_turn(const Eigen::Isometry3d& T_g, const Eigen::Vector3d& p2) {
    const Eigen::Vector3d v = T_g * p2;
    double a = fast_atan2(v.z(), v.y()) / kTwoPi;  // (-1/2, 1/2]
    a -= std::floor(a);                            // [0, 1)
    return static_cast<std::uint32_t>(std::min(a * 4294967296.0, 4294967295.0));
}
}  // namespace

PpfFeatures::PpfFeatures(const PpfSettings& s) : settings_(s) {
    if (s.sampling <= 0) throw std::invalid_argument("PPF sampling must be > 0");
    // Angle bin k holds [k pi / A, (k+1) pi / A): compare cosines with the bin edges instead of taking acos.
    for (int k = 1; k < s.angle_bins; ++k) edges_.push_back(std::cos(k * M_PI / s.angle_bins));
    sin_c_ = std::sin(s.coplanar_deg * M_PI / 180.0);
    cos_c_ = std::cos(s.coplanar_deg * M_PI / 180.0);
    // The bins by table: three per pair, and a binary search's branches were 6 % of a job (perf, seed 106).
    // Each slot holds at most one edge when the edges lie more than a slot apart (15 bins: 0.022 at the
    // narrowest, a slot 0.001); otherwise angle_bin searches.
    slots_.resize(kSlots);
    for (int k = 0; k < kSlots; ++k) {
        const double lo = -1.0 + 2.0 * k / kSlots, hi = -1.0 + 2.0 * (k + 1) / kSlots;
        Slot& slot = slots_[k];
        slot.edge = -2.0;
        slot.bin = 0;
        for (double e : edges_) {
            if (hi <= e)
                ++slot.bin;  // every cosine in the slot is below this edge
            else if (lo <= e) {
                if (slot.edge != -2.0) {  // two edges in one slot: no table
                    slots_.clear();
                    return;
                }
                slot.edge = e;
            }
        }
    }
}

int PpfFeatures::angle_bin(double c) const {
    if (!slots_.empty()) {
        const int k = std::clamp(static_cast<int>((c + 1.0) * (0.5 * kSlots)), 0, kSlots - 1);
        const Slot& slot = slots_[k];
        // Past the slot's end by rounding (c at or beyond +-1): the search below decides.
        if (c >= -1.0 + 2.0 * k / kSlots && c < -1.0 + 2.0 * (k + 1) / kSlots)
            return slot.bin + (c <= slot.edge ? 1 : 0);
    }
    // edges_ decrease with the angle: the bin is the number of edges whose angle the pair's angle reaches.
    int lo = 0, hi = static_cast<int>(edges_.size());
    while (lo < hi) {
        const int mid = (lo + hi) / 2;
        if (c <= edges_[mid])
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

int PpfFeatures::key(const Eigen::Vector3d& p1, const Eigen::Vector3d& n1, const Eigen::Vector3d& p2,
                     const Eigen::Vector3d& n2, int* distance_bin) const {
    const Eigen::Vector3d d = p2 - p1;
    const double dist2 = d.squaredNorm();
    const double s = settings_.sampling;
    if (dist2 < s * s) return -1;
    const double dist = std::sqrt(dist2);
    const Eigen::Vector3d u = d / dist;
    const double c1 = n1.dot(u), c2 = n2.dot(u), c3 = n1.dot(n2);
    if (std::abs(c3) > cos_c_ && std::abs(c1) < sin_c_) return -1;  // one plane: no shape
    *distance_bin = static_cast<int>(dist / s);
    const int A = settings_.angle_bins;
    return (angle_bin(c1) * A + angle_bin(c2)) * A + angle_bin(c3);
}

Eigen::Isometry3d ppf_align_to_x(const Eigen::Vector3d& p, const Eigen::Vector3d& n) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::Quaterniond::FromTwoVectors(n, Eigen::Vector3d::UnitX()).toRotationMatrix();
    T.translation() = -(T.linear() * p);
    return T;
}

PpfModel::PpfModel(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& normals,
                   const PpfSettings& settings)
    : settings_(settings), features_(settings), points_(points), normals_(normals) {
    set_extent();
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
    // Features that half the model's pairs share (two perpendicular faces of a block) are shared by every
    // prismatic thing in the cell too: they cost most of the voting and carry little evidence.
    std::size_t used = 0;
    for (int k = 0; k < nkeys; ++k) used += offsets_[k + 1] > offsets_[k];
    max_bucket_ = used ? static_cast<std::size_t>(settings_.bucket_cap * offsets_.back() / used) : 0;
    // Only the buckets that vote are kept: the others are most of the pairs (seed 106: 248 k of 881 k pairs
    // of fiducial A are kept, in 2 MB instead of 7), and a smaller table is read from nearer caches.
    live_.assign(static_cast<std::size_t>(nkeys) / 64 + 1, 0);
    for (int k = 0; k < nkeys; ++k) {
        const std::uint32_t size = offsets_[k + 1] - offsets_[k];
        if (size > 0 && size <= max_bucket_)
            live_[static_cast<std::size_t>(k) >> 6] |= std::uint64_t(1) << (k & 63);
    }
    for (int k = nkeys - 1; k >= 0; --k) offsets_[k + 1] = votes(k) ? offsets_[k + 1] - offsets_[k] : 0;
    offsets_[0] = 0;
    std::partial_sum(offsets_.begin(), offsets_.end(), offsets_.begin());
    entries_.resize(offsets_.back());
    std::vector<std::uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = 0; j < n; ++j) {
            const int k = keys[i * n + j];
            if (k < 0 || !votes(k)) continue;
            entries_[fill[k]++] = {static_cast<std::uint32_t>(i * settings_.alpha_bins),
                                   pair_turn(T_g[i], points_[j])};
        }
}

PpfModel::PpfModel(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& normals,
                   const PpfSettings& settings, std::vector<std::uint32_t> offsets,
                   std::vector<Entry> entries, std::size_t max_bucket)
    : settings_(settings),
      features_(settings),
      points_(points),
      normals_(normals),
      offsets_(std::move(offsets)),
      entries_(std::move(entries)),
      max_bucket_(max_bucket) {
    set_extent();
    const std::size_t nkeys = static_cast<std::size_t>(distance_bins_) * settings_.angle_bins *
                              settings_.angle_bins * settings_.angle_bins;
    if (offsets_.size() != nkeys + 1 || offsets_.front() != 0 || offsets_.back() != entries_.size())
        throw std::invalid_argument("PPF model: the table does not fit the points");
    live_.assign(nkeys / 64 + 1, 0);
    for (std::size_t k = 0; k < nkeys; ++k) {
        if (offsets_[k + 1] < offsets_[k])
            throw std::invalid_argument("PPF model: the table's offsets decrease");
        // Built tables hold only the keys that vote (the constructor above).
        if (offsets_[k + 1] > offsets_[k]) live_[k >> 6] |= std::uint64_t(1) << (k & 63);
    }
    for (const Entry& e : entries_)
        if (e.row % settings_.alpha_bins != 0 || e.row / settings_.alpha_bins >= points_.size())
            throw std::invalid_argument("PPF model: an entry names no point");
}

void PpfModel::set_extent() {
    if (points_.size() != normals_.size() || points_.empty())
        throw std::invalid_argument("PPF model needs points with normals");
    // An entry's row (index x alpha bins) is 32 bits.
    if (settings_.alpha_bins < 1 || points_.size() > std::numeric_limits<std::uint32_t>::max() /
                                                         static_cast<std::size_t>(settings_.alpha_bins))
        throw std::invalid_argument("PPF model: too many points, or no alpha bins");
    Eigen::AlignedBox3d box;
    for (const auto& p : points_) box.extend(p);
    diameter_ = box.diagonal().norm();
    center_ = box.center();
    // The table has a slot per (distance, angle, angle, angle) bin, counted in int: a model far larger than
    // the sampling step (a fiducial 10^6 times the scan, a wrong unit) overflowed 15 * 334094730 and then
    // asked for terabytes. Checked in floating point, before any cast.
    const double A = settings_.angle_bins;
    const double bins = std::ceil(diameter_ / settings_.sampling) + 2;
    if (!std::isfinite(diameter_) || !(settings_.sampling > 0) || !(bins * A * A * A < (1 << 28)))
        throw std::invalid_argument("PPF model: the model is " +
                                    std::to_string(diameter_ / settings_.sampling) +
                                    " sampling steps across, more than a feature table can hold (a model far "
                                    "larger than the point spacing: a wrong unit?)");
    distance_bins_ = static_cast<int>(bins);
}

int PpfModel::key(const Eigen::Vector3d& p1, const Eigen::Vector3d& n1, const Eigen::Vector3d& p2,
                  const Eigen::Vector3d& n2) const {
    int db = 0;
    const int k = features_.key(p1, n1, p2, n2, &db);
    return k < 0 ? -1 : key_of(k, db);
}

std::pair<const PpfModel::Entry*, const PpfModel::Entry*> PpfModel::lookup(int k) const {
    if (k < 0 || k + 1 >= static_cast<int>(offsets_.size())) return {nullptr, nullptr};
    return {entries_.data() + offsets_[k], entries_.data() + offsets_[k + 1]};
}

std::vector<PoseCandidate> ppf_detect(const PpfModel& model, const std::vector<Eigen::Vector3d>& scene_points,
                                      const std::vector<Eigen::Vector3d>& scene_normals) {
    return ppf_detect(std::vector<const PpfModel*>{&model}, scene_points, scene_normals).front();
}

namespace {

std::vector<PoseCandidate> cluster_votes(const PpfModel& model, const std::vector<PoseCandidate>& per_ref);

}  // namespace

std::vector<std::vector<PoseCandidate>> ppf_detect(const std::vector<const PpfModel*>& models,
                                                   const std::vector<Eigen::Vector3d>& scene_points,
                                                   const std::vector<Eigen::Vector3d>& scene_normals) {
    std::vector<std::vector<PoseCandidate>> out(models.size());
    if (models.empty() || scene_points.size() < 3) return out;
    const PpfSettings& s = models.front()->settings();
    for (const auto* m : models) {
        const PpfSettings& o = m->settings();
        if (o.sampling != s.sampling || o.angle_bins != s.angle_bins || o.alpha_bins != s.alpha_bins ||
            o.coplanar_deg != s.coplanar_deg || o.reference_stride != s.reference_stride ||
            o.min_references != s.min_references || o.partner_stride != s.partner_stride)
            throw std::invalid_argument("ppf_detect: the models differ in sampling or bins");
    }
    const PpfFeatures features(s);
    double reach = 0.0;
    for (const auto* m : models) reach = std::max(reach, m->diameter());
    // The scene's points in cubic cells: every partner of a reference point lies in the cells around its
    // own, `span` of them each side. The voting does not depend on the order its pairs come in (the running
    // maximum keeps the lowest index among equals), so the pairs need no sorting; a KD-tree's radius search
    // sorted every reference's 2000 or so partners (about 5 % of a job's time, perf on seed 106).
    Eigen::AlignedBox3d box;
    for (const auto& p : scene_points) box.extend(p);
    // Cells of half the reach, 5 x 5 x 5 around a reference: on a surface they hold about twice the points
    // within reach, against three times in 27 cells of the reach; the voting took 950-983 ms against
    // 994-1020 ms on seed 106 (summed over threads, four alternating runs; a third of the reach, 7 x 7 x 7,
    // was no better). Larger cells when far outliers stretch the box (at most 2 million cells).
    const CellFrame frame(box, std::max(0.5 * reach, 1e-9), 2.0e6);
    const int span = static_cast<int>(std::ceil(reach / frame.cell - 1e-9));  // cells each side within reach
    // The partners: every partner_stride-th point (the scene itself at the default stride of 1, uncopied).
    const std::size_t pstride = static_cast<std::size_t>(std::max(1, s.partner_stride));
    std::vector<Eigen::Vector3d> thinned;
    if (pstride > 1) {
        thinned.reserve(scene_points.size() / pstride + 1);
        for (std::size_t j = 0; j < scene_points.size(); j += pstride) thinned.push_back(scene_points[j]);
    }
    const std::vector<Eigen::Vector3d>& partners = pstride > 1 ? thinned : scene_points;
    const CellBuckets cells = bucket_by_cell(frame, partners);
    const double reach2 = reach * reach;

    const int nalpha = s.alpha_bins;
    std::vector<std::size_t> refs;
    // Every k-th point as reference, but at least about min_references on a small scene.
    const std::size_t stride = std::clamp<std::size_t>(scene_points.size() / std::max(1, s.min_references), 1,
                                                       static_cast<std::size_t>(s.reference_stride));
    for (std::size_t r = 0; r < scene_points.size(); r += stride) refs.push_back(r);

    // Each reference point keeps its best pose per model (Drost §3.3); per-reference slots keep it
    // deterministic.
    const std::size_t M = models.size();
    std::vector<PoseCandidate> per_ref(refs.size() * M);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, refs.size(), 16), [&](const auto& range) {
        std::vector<std::vector<std::uint16_t>> acc(M);
        std::vector<std::pair<std::uint16_t, std::size_t>> best(M);  // most votes per model, and where
        for (std::size_t m = 0; m < M; ++m) acc[m].resize(models[m]->size() * nalpha);
        std::vector<std::uint32_t> idx;
        for (std::size_t ri = range.begin(); ri != range.end(); ++ri) {
            const std::size_t r = refs[ri];
            const Eigen::Vector3d& pr = scene_points[r];
            const Eigen::Vector3d& nr = scene_normals[r];
            const Eigen::Isometry3d T_sg = ppf_align_to_x(pr, nr);
            for (auto& a : acc) std::fill(a.begin(), a.end(), 0);
            for (auto& bt : best) bt = {0, 0};
            idx.clear();
            const Eigen::Array3i c = frame.clamped_cell(pr);
            for (int z = std::max(0, c.z() - span); z <= std::min(frame.nz - 1, c.z() + span); ++z)
                for (int y = std::max(0, c.y() - span); y <= std::min(frame.ny - 1, c.y() + span); ++y)
                    for (int x = std::max(0, c.x() - span); x <= std::min(frame.nx - 1, c.x() + span); ++x) {
                        const std::size_t ci = frame.index(x, y, z);
                        for (std::uint32_t q = cells.start[ci]; q < cells.start[ci + 1]; ++q) {
                            const std::uint32_t j = cells.order[q];
                            if ((partners[j] - pr).squaredNorm() <= reach2)
                                idx.push_back(static_cast<std::uint32_t>(j * pstride));
                        }
                    }
            for (const std::uint32_t j : idx) {
                if (j == r) continue;
                int db = 0;
                const int ak = features.key(pr, nr, scene_points[j], scene_normals[j], &db);
                if (ak < 0) continue;
                bool have_turn =
                    false;  // the scene pair's angle, computed when some model has entries for it
                std::uint32_t turn_s = 0;
                for (std::size_t m = 0; m < M; ++m) {
                    const PpfModel& model = *models[m];
                    const int key = model.key_of(ak, db);
                    if (!model.votes(key)) continue;  // no entries, or too many
                    const auto [b, e] = model.lookup(key);
                    if (!have_turn) {
                        turn_s = pair_turn(T_sg, scene_points[j]);
                        have_turn = true;
                    }
                    std::uint16_t* votes = acc[m].data();
                    auto& [top, top_at] = best[m];
                    for (const auto* it = b; it != e; ++it) {
                        // The bin of (scene angle - model angle) mod one turn.
                        const std::uint32_t d = turn_s - it->turn;
                        const std::size_t ab = (static_cast<std::uint64_t>(d) * nalpha) >> 32;
                        // The entry holds its point's row (index x alpha bins): one multiplication less
                        // per vote, 5 % less time in the voting (seed 106: 976-982 ms against 1030-1042,
                        // summed over the threads, four alternating runs).
                        const std::size_t at = it->row + ab;
                        auto& v = votes[at];
                        if (v < 65535) ++v;
                        // The running maximum (the first index among equals, as a scan would find it).
                        if (v > top || (v == top && at < top_at)) {
                            top = v;
                            top_at = at;
                        }
                    }
                }
            }
            for (std::size_t m = 0; m < M; ++m) {
                if (best[m].first == 0) continue;
                const std::size_t bi = best[m].second;
                const std::size_t mi = bi / nalpha;
                const double alpha = (static_cast<double>(bi % nalpha) + 0.5) / nalpha * kTwoPi;
                const Eigen::Isometry3d T_mg =
                    ppf_align_to_x(models[m]->points()[mi], models[m]->normals()[mi]);
                PoseCandidate c;
                c.T_scene_model = T_sg.inverse() * Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitX()) * T_mg;
                c.votes = best[m].first;
                per_ref[ri * M + m] = c;
            }
        }
    });
    for (std::size_t m = 0; m < M; ++m) {
        std::vector<PoseCandidate> mine;
        mine.reserve(refs.size());
        for (std::size_t ri = 0; ri < refs.size(); ++ri) mine.push_back(per_ref[ri * M + m]);
        out[m] = cluster_votes(*models[m], mine);
    }
    return out;
}

namespace {

std::vector<PoseCandidate> cluster_votes(const PpfModel& model, const std::vector<PoseCandidate>& per_ref) {
    const PpfSettings& s = model.settings();
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
            // The translation first: most clusters lie farther, and their turn (an arc cosine) is not needed.
            if ((cl.rep.T_scene_model.translation() - c.T_scene_model.translation()).norm() >= dmax) continue;
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
    std::stable_sort(clusters.begin(), clusters.end(),
                     [](const auto& a, const auto& b) { return a.votes > b.votes; });
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

}  // namespace

}  // namespace partloc
