#pragma once
// printf-style formatting into a std::string, for the reasons and warnings that results carry.
#include <cstdio>
#include <string>

namespace partloc {

/// `pattern` (printf's) filled with `args`; at most 511 characters.
template <typename... Args>
std::string format(const char* pattern, Args... args) {
    char buf[512];
    std::snprintf(buf, sizeof buf, pattern, args...);
    return buf;
}

}  // namespace partloc
