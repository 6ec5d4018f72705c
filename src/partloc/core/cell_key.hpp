#pragma once
// Cubic cells named by their integer coordinates packed into one 64-bit key, and a key -> index hash table:
// for grids over a few thousand to a few hundred thousand occupied cells in a box of billions (the stock's
// surface grid, a scan's voxels).
#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace partloc::cells {

/// 21 bits per coordinate (z highest): ascending keys run x fastest, then y, then z. Coordinates must lie in
/// [0, 2^21).
using Key = std::uint64_t;
constexpr int kBits = 21;
constexpr Key kMask = (Key{1} << kBits) - 1;
constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

inline Key pack(const Eigen::Array3i& c) {
    return static_cast<Key>(c.x()) | static_cast<Key>(c.y()) << kBits |
           static_cast<Key>(c.z()) << (2 * kBits);
}
inline Eigen::Array3i unpack(Key k) {
    return {static_cast<int>(k & kMask), static_cast<int>((k >> kBits) & kMask),
            static_cast<int>((k >> (2 * kBits)) & kMask)};
}

/// Cubic cells of `edge` from `origin`: cell c spans origin + edge * [c, c + 1).
struct Lattice {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    double edge = 1.0;
    Eigen::Array3i cell_of(const Eigen::Vector3d& p) const {
        return ((p - origin) / edge).array().floor().cast<int>();
    }
    Eigen::Vector3d at(const Eigen::Array3i& c) const { return origin + edge * c.cast<double>().matrix(); }
};

/// Key -> index, open addressing with linear probing, growing at half full.
class KeyIndex {
  public:
    KeyIndex() { rehash(1024); }
    /// The key's value, kNone when absent.
    std::uint32_t find(Key key) const {
        for (std::size_t s = slot(key);; s = (s + 1) & mask_) {
            if (keys_[s] == key) return values_[s];
            if (keys_[s] == kEmpty) return kNone;
        }
    }
    /// Adds a key that is not there.
    void add(Key key, std::uint32_t value) {
        if (2 * (size_ + 1) > keys_.size()) rehash(2 * keys_.size());
        place(key, value);
        ++size_;
    }
    /// The key's value; adds it with `value` when absent.
    std::uint32_t find_or_add(Key key, std::uint32_t value) {
        const std::uint32_t v = find(key);
        if (v != kNone) return v;
        add(key, value);
        return value;
    }

  private:
    static constexpr Key kEmpty = ~Key{0};
    std::size_t slot(Key key) const {
        return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ull) >> 24) & mask_;
    }
    void place(Key key, std::uint32_t value) {
        std::size_t s = slot(key);
        while (keys_[s] != kEmpty) s = (s + 1) & mask_;
        keys_[s] = key;
        values_[s] = value;
    }
    void rehash(std::size_t capacity) {
        std::vector<Key> keys(capacity, kEmpty);
        std::vector<std::uint32_t> values(capacity, kNone);
        keys.swap(keys_);
        values.swap(values_);
        mask_ = capacity - 1;
        for (std::size_t i = 0; i < keys.size(); ++i)
            if (keys[i] != kEmpty) place(keys[i], values[i]);
    }
    std::vector<Key> keys_;
    std::vector<std::uint32_t> values_;
    std::size_t mask_ = 0, size_ = 0;
};

}  // namespace partloc::cells
