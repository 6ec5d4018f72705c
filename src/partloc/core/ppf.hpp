#pragma once
// Global fit with no initial guess: point-pair-feature voting (Drost et al., "Model globally, match
// locally", CVPR 2010). Why not Open3D's FPFH + RANSAC: on a cell cluttered with planes (pallet, chuck,
// trunnion) FPFH descriptors of flat and prismatic regions are alike, and the tutorial pipeline registered
// 0 of 6 scans (issue 2). Pair features of points on *different* faces keep the block's unique geometry;
// pairs on one plane carry no shape and are skipped, so planar clutter casts no votes.
#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

namespace partloc {

struct PpfSettings {
    double sampling = 0.0;  ///< distance step and point sampling (job units); required > 0
    int angle_bins = 15;    ///< bins over [0, pi] for the three feature angles (12 degrees each)
    int alpha_bins = 30;    ///< bins over 2 pi for the rotation about the normal (12 degrees each)
    /// Every k-th scene point is a reference point: every 16th registers as many scans as every 8th at half
    /// the votes, the largest part of a scan's time (docs/history.md, PPF settings).
    int reference_stride = 16;
    /// ...but at least about this many references on a small scene (scans of 250 k points have 10-15
    /// thousand points at the sampling, so this decides their stride); fewer lost scans of the tests.
    int min_references = 1000;
    /// Every k-th scene point (by index) is a partner of each reference point; thinning them lost scans that
    /// every point keeps (docs/history.md, PPF settings).
    int partner_stride = 1;
    double coplanar_deg =
        8.0;  ///< a pair whose normals and joining line are within this of coplanar is skipped
    /// Pose clusters returned, most votes first; each is screened by a coarse fit (a third of a scan's time
    /// at 32, which registered no more scans than 16).
    int max_candidates = 16;
    int per_location = 2;  ///< at most this many candidates within a quarter diameter of each other
    /// Features shared by more model pairs than this x the mean cast no votes: common features (planes) cast
    /// most of the votes and tell little (docs/history.md, PPF settings).
    double bucket_cap = 2.0;
    double cluster_rotation_deg = 12.0;  ///< poses closer than this and cluster_distance join one cluster
    double cluster_distance = 0.0;       ///< (job units); 0: 2 * sampling
};

/// The pair feature of Drost et al.: distance and three angles, binned. Angle bins come from comparing
/// cosines with the bins' edges (no inverse trigonometry), so that one scene pair is binned once for every
/// model.
class PpfFeatures {
  public:
    explicit PpfFeatures(const PpfSettings& settings);
    /// Angle part of the key of an oriented pair (unit normals), and its distance bin; -1 for a pair that is
    /// skipped (closer than the sampling, or on one plane).
    int key(const Eigen::Vector3d& p1, const Eigen::Vector3d& n1, const Eigen::Vector3d& p2,
            const Eigen::Vector3d& n2, int* distance_bin) const;
    int angle_bin(double cosine) const;

  private:
    PpfSettings settings_;
    std::vector<double> edges_;
    double sin_c_ = 0.0, cos_c_ = 1.0;
    /// angle_bin by table: the cosine's slot of [-1, 1] gives the bin at the slot's upper end and the one
    /// edge the slot may hold (slots are narrower than the gap between two edges).
    struct Slot {
        double edge;  ///< an edge within the slot, or -2 (none)
        int bin;      ///< the bin of the slot's upper end
    };
    static constexpr int kSlots = 2048;
    std::vector<Slot> slots_;
};

/// The model's pair features, hashed. Built once per model, searched from many threads.
class PpfModel {
  public:
    /// points, normals: the model sampled at about settings.sampling, unit normals, in the model frame.
    PpfModel(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& normals,
             const PpfSettings& settings);

    struct Entry {
        std::uint32_t row;  ///< the first point's row in a vote accumulator: its index times alpha_bins
        /// Angle of the pair about the first normal as a fraction of a turn, fixed point (2^32 = one turn):
        /// the difference of two such angles wraps around by itself in unsigned arithmetic.
        std::uint32_t turn;
    };
    /// A table as built before from these points and settings (offsets(), entries() and max_bucket() of
    /// it), e.g. read back from the model cache. Throws std::invalid_argument when the parts do not fit
    /// together (the offsets' count or order, an entry's point).
    PpfModel(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& normals,
             const PpfSettings& settings, std::vector<std::uint32_t> offsets, std::vector<Entry> entries,
             std::size_t max_bucket);

    const PpfSettings& settings() const { return settings_; }
    double diameter() const { return diameter_; }
    const Eigen::Vector3d& center() const { return center_; }
    std::size_t size() const { return points_.size(); }
    std::size_t max_bucket() const { return max_bucket_; }

    /// Feature key of an oriented pair, or -1 for a pair that is skipped (too close, coplanar, too far).
    int key(const Eigen::Vector3d& p1, const Eigen::Vector3d& n1, const Eigen::Vector3d& p2,
            const Eigen::Vector3d& n2) const;
    /// Table key of a pair with angle key `angle_key` (from PpfFeatures) and distance bin `distance_bin`.
    int key_of(int angle_key, int distance_bin) const {
        if (distance_bin >= distance_bins_) return -1;
        const int A = settings_.angle_bins;
        return distance_bin * A * A * A + angle_key;
    }

    /// Entries with this key: [begin, end).
    std::pair<const Entry*, const Entry*> lookup(int key) const;
    /// Whether key k (0 <= k < table keys, or -1) has entries and no more than max_bucket(): one bit per key
    /// (11 kB for 15 angle bins), so that the four of five scene pairs that fail it (seed 106) need not read
    /// the offsets (0.4 MB). No gain in time measurable on this machine; kept as the simpler test.
    bool votes(int k) const { return k >= 0 && (live_[static_cast<std::size_t>(k) >> 6] >> (k & 63) & 1u); }

    const std::vector<Eigen::Vector3d>& points() const { return points_; }
    const std::vector<Eigen::Vector3d>& normals() const { return normals_; }
    /// The table, CSR by key: the entries of key k are entries()[offsets()[k], offsets()[k + 1]).
    const std::vector<std::uint32_t>& offsets() const { return offsets_; }
    const std::vector<Entry>& entries() const { return entries_; }

  private:
    /// Checks the points (with normals, not too many for the entries' rows), then diameter_, center_ and
    /// distance_bins_ from them.
    void set_extent();
    PpfSettings settings_;
    PpfFeatures features_;
    std::vector<Eigen::Vector3d> points_, normals_;
    double diameter_ = 0.0;
    Eigen::Vector3d center_ = Eigen::Vector3d::Zero();
    int distance_bins_ = 0;
    std::vector<std::uint32_t> offsets_;  ///< CSR: entries of key k are entries_[offsets_[k], offsets_[k+1])
    std::vector<Entry> entries_;
    std::size_t max_bucket_ = 0;
    std::vector<std::uint64_t> live_;  ///< votes(k), by bit
};

struct PoseCandidate {
    Eigen::Isometry3d T_scene_model = Eigen::Isometry3d::Identity();
    double votes = 0.0;
};

/// Votes for model poses in a scene sampled at about the model's sampling, with unit normals. Returns up to
/// settings.max_candidates pose clusters, most votes first. Deterministic for any number of threads.
std::vector<PoseCandidate> ppf_detect(const PpfModel& model, const std::vector<Eigen::Vector3d>& scene_points,
                                      const std::vector<Eigen::Vector3d>& scene_normals);

/// The same for several models in one pass over the scene: the neighbour search and each pair's feature are
/// computed once and vote in every model's table (the models must share sampling and bins). One candidate
/// list per model, in the models' order.
std::vector<std::vector<PoseCandidate>> ppf_detect(const std::vector<const PpfModel*>& models,
                                                   const std::vector<Eigen::Vector3d>& scene_points,
                                                   const std::vector<Eigen::Vector3d>& scene_normals);

/// Alignment of an oriented point to the origin with its normal along +x (Drost's T_{m->g}).
Eigen::Isometry3d ppf_align_to_x(const Eigen::Vector3d& p, const Eigen::Vector3d& n);

}  // namespace partloc
