#include "files.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace iwr::app {

namespace {

std::string errno_text(int err) { return std::strerror(err); }

void write_all(int fd, const std::string& data, const std::string& tmp) {
    const char* p = data.data();
    std::size_t left = data.size();
    while (left > 0) {
        const ssize_t n = ::write(fd, p, left);
        if (n < 0) {
            if (errno == EINTR) continue;  // a signal arrived (SIGINT, SIGTERM): keep writing
            throw std::runtime_error(tmp + ": cannot write (" + errno_text(errno) + ")");
        }
        p += n;
        left -= static_cast<std::size_t>(n);
    }
}

}  // namespace

void atomic_write(const std::string& path, const std::string& data) {
    const std::size_t slash = path.find_last_of('/');
    const std::string dir = slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
    const std::string base = slash == std::string::npos ? path : path.substr(slash + 1);
    if (base.empty()) throw std::runtime_error(path + ": not a file name");
    std::string tmpl = (dir == "." && slash == std::string::npos ? "" : path.substr(0, slash + 1)) + "." +
                       base + ".XXXXXX";
    std::vector<char> name(tmpl.begin(), tmpl.end());
    name.push_back('\0');
    const int fd = ::mkstemp(name.data());
    if (fd < 0) {
        const int err = errno;
        throw std::runtime_error(path + ": cannot create a temporary file in " + dir + " (" +
                                 errno_text(err) + ")");
    }
    const std::string tmp(name.data());
    try {
        // mkstemp creates the file 0600; give it the usual permissions (umask applies).
        const mode_t mask = ::umask(0);
        ::umask(mask);
        ::fchmod(fd, 0666 & ~mask);
        write_all(fd, data, tmp);
        if (::fsync(fd) != 0) throw std::runtime_error(tmp + ": fsync failed (" + errno_text(errno) + ")");
        if (::close(fd) != 0) throw std::runtime_error(tmp + ": close failed (" + errno_text(errno) + ")");
    } catch (...) {
        ::close(fd);
        ::unlink(tmp.c_str());
        throw;
    }
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
        const int err = errno;
        ::unlink(tmp.c_str());
        throw std::runtime_error(path + ": cannot replace (" + errno_text(err) + ")");
    }
    // Make the rename itself durable.
    const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
    if (dfd >= 0) {
        ::fsync(dfd);
        ::close(dfd);
    }
}

std::uint64_t hash64(const std::string& s) { return Hash64().bytes(s.data(), s.size()).value(); }

std::string hex64(std::uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

std::string json_number(double v) {
    if (!std::isfinite(v)) return "null";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    std::string out = buf;
    // Keep it a float for JSON readers that tell 1 from 1.0 (Python's json does).
    if (out.find_first_of(".e") == std::string::npos) out += ".0";
    return out;
}

std::string csv_number(double v) {
    if (std::isnan(v)) return "nan";
    if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

std::string json_string(const std::string& s) {
    std::string out = "\"";
    for (const char ch : s) {
        const unsigned char c = static_cast<unsigned char>(ch);
        switch (c) {
            case '"': out += "\\\""; break;
            case '\\': out += "\\\\"; break;
            case '\n': out += "\\n"; break;
            case '\r': out += "\\r"; break;
            case '\t': out += "\\t"; break;
            default:
                if (c < 0x20) {
                    char buf[8];
                    std::snprintf(buf, sizeof buf, "\\u%04x", c);
                    out += buf;
                } else {
                    out += ch;  // UTF-8 passes through
                }
        }
    }
    return out + "\"";
}

}  // namespace iwr::app
