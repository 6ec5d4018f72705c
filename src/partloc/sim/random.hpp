#pragma once
// A small counter-based random generator: every ray and every random choice draws from a stream keyed by
// (seed, index), so the simulation gives the same numbers whatever the thread count or evaluation order.
#include <cmath>
#include <cstdint>

namespace partloc::sim {

/// SplitMix64 (Steele, Lea and Flood 2014): one 64-bit state, full period, good enough for simulation.
class Rng {
  public:
    explicit Rng(std::uint64_t seed, std::uint64_t stream = 0)
        : state_(mix(seed ^ mix(stream + 0x632BE59BD9B4E019ull))) {}

    std::uint64_t next() {
        state_ += 0x9E3779B97F4A7C15ull;
        return mix(state_);
    }
    /// Uniform in [0, 1).
    double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
    /// Uniform in [lo, hi).
    double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
    /// Uniform integer in [lo, hi].
    int integer(int lo, int hi) {
        return lo + static_cast<int>(uniform() * static_cast<double>(hi - lo + 1));
    }
    /// Standard normal (Box-Muller).
    double gaussian() {
        const double u1 = 1.0 - uniform();  // in (0, 1]
        const double u2 = uniform();
        return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
    }

  private:
    static std::uint64_t mix(std::uint64_t z) {
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    std::uint64_t state_;
};

}  // namespace partloc::sim
