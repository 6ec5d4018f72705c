#pragma once
// Helpers the test files share: whole-file reads and writes, a temporary folder, and the check that a job
// file is refused with a given phrase.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "partloc/io/job_io.hpp"

namespace partloc::test {

inline std::string slurp(const std::filesystem::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

inline void spit(const std::filesystem::path& p, const std::string& bytes) {
    std::filesystem::create_directories(p.parent_path());
    std::ofstream out(p, std::ios::binary);
    out << bytes;
}

/// A fresh folder under the system's temporary directory, removed with everything in it at the end.
struct TempFolder {
    std::filesystem::path dir;
    explicit TempFolder(const std::string& prefix = "partloc_test") {
        static std::atomic<int> n{0};
        dir = std::filesystem::temp_directory_path() /
              (prefix + "_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
        std::filesystem::remove_all(dir);
        std::filesystem::create_directories(dir);
    }
    ~TempFolder() {
        std::error_code ec;
        std::filesystem::remove_all(dir, ec);
    }
    TempFolder(const TempFolder&) = delete;
    TempFolder& operator=(const TempFolder&) = delete;
    std::filesystem::path write(const std::string& name, const std::string& text) const {
        spit(dir / name, text);
        return dir / name;
    }
};

/// Runs `command` in the shell; its exit code, or -1 when it did not exit normally.
inline int shell(const std::string& command) {
    const int status = std::system(command.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

/// io::load_job(job) must throw an InputError that names the job file, contains `phrase` and is one line.
inline void expect_job_error(const std::filesystem::path& job, const std::string& phrase) {
    try {
        io::load_job(job);
        ADD_FAILURE() << "no error; expected '" << phrase << "'";
    } catch (const io::InputError& e) {
        EXPECT_EQ(e.file(), job.string());
        EXPECT_NE(std::string(e.what()).find(phrase), std::string::npos) << e.what();
        EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
    }
}

}  // namespace partloc::test
