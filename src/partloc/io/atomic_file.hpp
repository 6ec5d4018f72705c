#pragma once
// Files appear whole or not at all (SPEC "Commands"): write to a temporary name beside the target, then
// rename over it.
#include <filesystem>
#include <functional>
#include <string>

namespace partloc::io {

/// Calls write(tmp_path) to produce the file at a temporary path in the same folder, then renames it to
/// `path`. If write throws or returns false, the temporary file is removed and std::runtime_error naming
/// `path` is thrown. Creates the parent folder when missing.
void write_atomically(const std::filesystem::path& path,
                      const std::function<bool(const std::filesystem::path& tmp_path)>& write);

/// Writes `text` to `path` atomically.
void write_text_atomically(const std::filesystem::path& path, const std::string& text);

}  // namespace partloc::io
