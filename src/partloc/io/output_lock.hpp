#pragma once
// One run at a time in an output folder (SPEC "Output folder": files appear whole, and a result.json is of
// the files beside it). Two runs into one folder interleaved their files: one job's result.json beside the
// other's report, both exit 0.
#include <filesystem>
#include <stdexcept>
#include <string>

namespace partloc::io {

/// Another run holds the folder.
struct FolderBusy : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// An exclusive lock on an output folder, held while the object lives: flock(2) on DIR/.partloc.lock, which
/// the system releases when the process ends however it ends, so a killed run never leaves the folder
/// locked; the file is removed when the lock is given up. Once the lock is held, the temporaries that killed
/// runs left (io/atomic_file.hpp's .tmp-PID-N-* names, in DIR and its sub-folders) are removed: no run can be
/// writing them.
class OutputFolderLock {
  public:
    /// Creates `dir` when missing and takes the lock. Throws FolderBusy when another process holds it, and
    /// std::runtime_error naming the folder when the lock file cannot be made (a read-only folder).
    explicit OutputFolderLock(const std::filesystem::path& dir);
    ~OutputFolderLock();
    OutputFolderLock(const OutputFolderLock&) = delete;
    OutputFolderLock& operator=(const OutputFolderLock&) = delete;

    /// The temporaries removed when the lock was taken.
    std::size_t removed_temporaries() const { return removed_; }

  private:
    std::filesystem::path lock_;
    int fd_ = -1;
    std::size_t removed_ = 0;
};

/// True for a name atomic_file.cpp gives its temporaries: ".tmp-" PID "-" N "-" target name.
bool is_atomic_temporary(const std::string& filename);

}  // namespace partloc::io
