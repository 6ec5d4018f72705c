#pragma once
// The paper's pipeline (§3.4) on PCL, on a partloc Job: for each scan the fiducial with the largest metric
// (1) wins if it passes the threshold, T_r = T_f^-1 T_o T_d (2); the registered scans' workpiece region is
// merged and the reference surfaces fitted (§3.4.2). Built only with PCL (PARTLOC_BENCH_WITH_PCL).
#include "common.hpp"

namespace partloc::bench {

struct PaperSettings {
    double model_spacing = 0.5;  ///< mm, Poisson-disk radius of the point models (§3.2 step 5: 0.0005 m)
    std::uint64_t seed = 1;
};

/// True when this build has the PCL part.
bool paper_pipeline_available();

/// Throws std::runtime_error when the build has no PCL.
MethodOutcome run_paper(const Job& job, const PaperSettings& settings = {});

}  // namespace partloc::bench
