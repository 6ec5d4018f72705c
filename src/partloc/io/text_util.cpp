// Helpers shared by the format parsers: reading a file whole, and walking text.
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <memory>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

namespace fs = std::filesystem;

std::string read_file_bytes(const fs::path& path, const std::string& name) {
    const std::string where = path.string() == name ? "" : " (looked for " + path.string() + ")";
    std::error_code ec;
    const fs::file_status status = fs::status(path, ec);
    if (status.type() == fs::file_type::not_found) throw InputError(name, "no such file" + where);
    if (status.type() == fs::file_type::directory) throw InputError(name, "is a folder, not a file" + where);
    // A device (/dev/zero, /dev/urandom) or a pipe has no size and no end: reading it whole would grow until
    // the memory is gone, or wait forever.
    if (status.type() != fs::file_type::regular && status.type() != fs::file_type::unknown)
        throw InputError(name, "is not a regular file (a device, a pipe or a socket)" + where);

    std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
    if (!file) throw InputError(name, std::string("cannot be opened (") + std::strerror(errno) + ")" + where);
    std::string bytes;
    // Read into a string of the file's size at once: growing it by doubling copied and touched twice a
    // scan's bytes (the load of seed 106's six scans spent a third of its time in page faults).
    const auto size = fs::file_size(path, ec);
    if (!ec && size > 0 && size < (std::size_t{1} << 40)) bytes.reserve(static_cast<std::size_t>(size));
    char buffer[1 << 16];
    std::size_t n = 0;
    while ((n = std::fread(buffer, 1, sizeof buffer, file.get())) > 0) bytes.append(buffer, n);
    if (std::ferror(file.get()))
        throw InputError(name, std::string("cannot be read (") + std::strerror(errno) + ")");
    if (bytes.empty()) throw InputError(name, "file is empty");
    return bytes;
}

bool parse_number(std::string_view token, double& value) {
    // from_chars takes no leading '+', but files written by printf("%+f") have one.
    if (token.size() > 1 && token[0] == '+' && token[1] != '-') token.remove_prefix(1);
    if (token.empty()) return false;
    const char* end = token.data() + token.size();
    const auto [ptr, ec] = std::from_chars(token.data(), end, value);
    // A value out of double's range is an error (ec set), not silently inf.
    return ec == std::errc() && ptr == end;
}

bool looks_binary(std::string_view bytes) {
    return bytes.substr(0, 4096).find('\0') != std::string_view::npos;
}

std::vector<std::string_view> split_columns(std::string_view line) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    const auto is_space = [](char c) { return c == ' ' || c == '\t'; };
    while (i < line.size()) {
        while (i < line.size() && is_space(line[i])) ++i;
        if (i >= line.size()) break;
        std::size_t j = i;
        while (j < line.size() && !is_space(line[j]) && line[j] != ',' && line[j] != ';') ++j;
        out.push_back(line.substr(i, j - i));
        i = j;
        while (i < line.size() && is_space(line[i])) ++i;
        if (i < line.size() && (line[i] == ',' || line[i] == ';')) {
            ++i;
            // "1,,3" and a trailing "1,2," hold empty fields; keep them so the column count tells.
            std::size_t k = i;
            while (k < line.size() && is_space(line[k])) ++k;
            if (k >= line.size() || line[k] == ',' || line[k] == ';') out.push_back(std::string_view());
        }
    }
    return out;
}

bool LineReader::next(std::string_view& line) {
    if (pos_ >= text_.size()) return false;
    std::size_t end = text_.find('\n', pos_);
    if (end == std::string_view::npos) end = text_.size();
    line = text_.substr(pos_, end - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end + 1;
    ++line_number_;
    return true;
}

bool TokenReader::next(std::string_view& token) {
    while (pos_ < text_.size()) {
        const char c = text_[pos_];
        if (c == '\n') {
            ++line_;
        } else if (c != ' ' && c != '\t' && c != '\r' && c != '\f' && c != '\v') {
            break;
        }
        ++pos_;
    }
    if (pos_ >= text_.size()) return false;
    std::size_t end = pos_;
    while (end < text_.size()) {
        const char c = text_[end];
        if (c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v') break;
        ++end;
    }
    token = text_.substr(pos_, end - pos_);
    pos_ = end;
    return true;
}

std::string plural_of(const std::string& element) {
    if (element == "vertex") return "vertices";
    if (element == "face") return "faces";
    if (element == "point") return "points";
    return "'" + element + "' elements";
}

}  // namespace partloc::io::detail
