#pragma once
// Tests print nothing unless they fail: `note(...)` (printf-style) keeps the figures a test measured, and a
// listener prints them after the test's failure messages, only when the test failed.
#include <gtest/gtest.h>

#include <cstdarg>
#include <cstdio>
#include <string>

namespace partloc::test {

inline std::string& notes() {
    static std::string buffer;
    return buffer;
}

#if defined(__GNUC__)
__attribute__((format(printf, 1, 2)))
#endif
inline void
note(const char* format, ...) {
    char line[2048];
    va_list args;
    va_start(args, format);
    std::vsnprintf(line, sizeof line, format, args);
    va_end(args);
    notes() += line;
}

class NoteListener : public ::testing::EmptyTestEventListener {
    void OnTestStart(const ::testing::TestInfo&) override { notes().clear(); }
    void OnTestEnd(const ::testing::TestInfo& info) override {
        if (info.result() != nullptr && info.result()->Failed() && !notes().empty())
            std::fprintf(stderr, "%s notes:\n%s", info.name(), notes().c_str());
        notes().clear();
    }
};

// One listener per test program, appended before RUN_ALL_TESTS; gtest owns and deletes it.
inline const bool note_listener_installed = [] {
    ::testing::UnitTest::GetInstance()->listeners().Append(new NoteListener);
    return true;
}();

}  // namespace partloc::test
