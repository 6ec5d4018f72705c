#pragma once
// Union-find's root with path halving, for the joins into faces and regions (core/allowance.cpp,
// pipeline/job_checks.cpp): parent[i] == i at a root.
#include <vector>

namespace partloc {

inline int find_root(std::vector<int>& parent, int i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

}  // namespace partloc
