#include "iwr/binary_io.hpp"

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <fstream>

namespace iwr::io {

std::string hex64(std::uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

// --- Reader -----------------------------------------------------------------------------------------

void Reader::fail(const std::string& what) const { throw FormatError(context_ + what); }

const char* Reader::take(std::size_t k, const char* field) {
    if (k > n_ - i_) fail(std::string("truncated while reading ") + field);
    const char* p = p_ + i_;
    i_ += k;
    return p;
}

std::int64_t Reader::i64_in(const char* field, std::int64_t lo, std::int64_t hi) {
    const std::int64_t v = i64(field);
    if (v < lo || v > hi)
        fail(std::string(field) + " is " + std::to_string(v) + ", outside [" + std::to_string(lo) +
             ", " + std::to_string(hi) + "]");
    return v;
}

std::size_t Reader::count(const char* field, std::size_t item_bytes) {
    const std::uint64_t n = u64(field);
    // The count is checked against what is left before anything of that size is allocated.
    if (item_bytes > 0 && n > remaining() / item_bytes)
        fail(std::string("truncated or corrupt: ") + field + " says " + std::to_string(n) +
             " items, more than the " + std::to_string(remaining()) + " bytes left can hold");
    return static_cast<std::size_t>(n);
}

std::string Reader::str(const char* field, std::size_t max_len) {
    const std::size_t n = count(field, 1);
    if (n > max_len)
        fail(std::string(field) + " is " + std::to_string(n) + " bytes long, more than " +
             std::to_string(max_len));
    return std::string(take(n, field), n);
}

std::string Reader::text(const char* field, std::size_t max_len, bool allow_empty) {
    std::string s = str(field, max_len);
    for (unsigned char c : s)
        if (c < 0x20 || c == 0x7f) fail(std::string(field) + ": holds a control character");
    // Well-formed UTF-8 (what Python decodes the text as): lead byte, continuation bytes, no
    // overlong forms, no surrogates, nothing beyond U+10FFFF.
    for (std::size_t i = 0; i < s.size();) {
        const auto c = static_cast<unsigned char>(s[i]);
        std::size_t len = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
        bool ok = len != 0 && i + len <= s.size();
        for (std::size_t j = 1; ok && j < len; ++j) ok = (static_cast<unsigned char>(s[i + j]) >> 6) == 0x2;
        if (ok && len > 1) {
            std::uint32_t cp = c & (0x7F >> len);
            for (std::size_t j = 1; j < len; ++j) cp = (cp << 6) | (static_cast<unsigned char>(s[i + j]) & 0x3F);
            const std::uint32_t least[5] = {0, 0, 0x80, 0x800, 0x10000};
            ok = cp >= least[len] && cp <= 0x10FFFF && !(cp >= 0xD800 && cp <= 0xDFFF);
        }
        if (!ok) fail(std::string(field) + ": not valid UTF-8 text (byte " + std::to_string(i) + ")");
        i += len;
    }
    if (!allow_empty && s.empty()) fail(std::string(field) + ": empty");
    return s;
}

bool Reader::flag(const char* field) {
    const std::uint8_t v = u8(field);
    if (v > 1) fail(std::string(field) + ": " + std::to_string(v) + ", expected 0 or 1");
    return v == 1;
}

std::vector<double> Reader::doubles(const char* field) {
    const std::size_t n = count(field, 8);
    std::vector<double> v(n);
    for (auto& x : v) x = f64(field);
    return v;
}

std::vector<double> Reader::doubles(const char* field, std::size_t n) {
    const std::size_t stored = count(field, 8);
    if (stored != n)
        fail(std::string(field) + " has " + std::to_string(stored) + " values; expected " +
             std::to_string(n));
    std::vector<double> v(n);
    for (auto& x : v) x = f64(field);
    return v;
}

void Reader::finish() {
    if (remaining() != 0) fail("corrupt: " + std::to_string(remaining()) + " unexpected bytes at the end");
}

// --- the sealed container ------------------------------------------------------------------------------

namespace {
constexpr std::size_t kHeader = 32;
}

std::string seal(const char magic[8], std::uint32_t version, const std::string& payload) {
    Writer w;
    w.data().reserve(kHeader + payload.size());
    w.raw(std::string(magic, 8));
    w.u32(version);
    w.u32(0);
    w.u64(payload.size());
    w.u64(hash64(payload.data(), payload.size()));
    w.raw(payload);
    return std::move(w.data());
}

std::string unseal(const std::string& bytes, const char magic[8], std::uint32_t version,
                   const std::string& context, const char* what) {
    return unseal(bytes, magic, version, version, nullptr, context, what);
}

std::string unseal(const std::string& bytes, const char magic[8], std::uint32_t oldest,
                   std::uint32_t newest, std::uint32_t* version, const std::string& context,
                   const char* what) {
    const std::string m(magic, 8);
    if (bytes.empty()) throw FormatError(context + "empty file; not " + what);
    if (bytes.size() < 8 || bytes.compare(0, 8, m) != 0) {
        if (bytes.size() < 8 && m.compare(0, bytes.size(), bytes) == 0)
            throw FormatError(context + "truncated: " + std::to_string(bytes.size()) +
                              " bytes, less than the header");
        throw FormatError(context + "not " + what + " (wrong magic bytes)");
    }
    if (bytes.size() < kHeader)
        throw FormatError(context + "truncated: " + std::to_string(bytes.size()) +
                          " bytes, less than the header");
    Reader h(bytes.data() + 8, kHeader - 8, context);
    const std::uint32_t v = h.u32("version");
    const std::uint32_t zero = h.u32("reserved");
    const std::uint64_t size = h.u64("payload size");
    const std::uint64_t checksum = h.u64("checksum");
    // The version first, so that another version of the format gets a clear message.
    if (v < oldest || v > newest || zero != 0)
        throw FormatError(context + "format version " + std::to_string(v) + "; this program reads version" +
                          (oldest == newest ? " " + std::to_string(newest)
                                            : "s " + std::to_string(oldest) + " to " + std::to_string(newest)));
    if (version) *version = v;
    const std::uint64_t have = bytes.size() - kHeader;
    if (have < size)
        throw FormatError(context + "truncated: " + std::to_string(bytes.size()) + " bytes of " +
                          (size > UINT64_MAX - kHeader ? std::string("more than 2^64")
                                                       : std::to_string(size + kHeader)));
    if (have > size)
        throw FormatError(context + "corrupt: " + std::to_string(have - size) + " bytes after the end");
    if (hash64(bytes.data() + kHeader, have) != checksum)
        throw FormatError(context + "corrupt: checksum mismatch (the file was modified or damaged)");
    return bytes.substr(kHeader);
}

// --- files ---------------------------------------------------------------------------------------------

std::string read_file(const std::string& path, const char* what, std::uint64_t max_bytes) {
    // O_NONBLOCK: opening a FIFO must not wait for a writer (it is refused just below).
    const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
        const int err = errno;
        if (err == ENOENT) throw FormatError(path + ": no such file");
        throw FormatError(path + ": cannot read " + what + " (" + std::strerror(err) + ")");
    }
    struct Closer {
        int fd;
        ~Closer() { ::close(fd); }
    } closer{fd};
    struct stat st {};
    if (::fstat(fd, &st) != 0) throw FormatError(path + ": cannot read " + what + " (" + std::strerror(errno) + ")");
    if (S_ISDIR(st.st_mode)) throw FormatError(path + ": is a folder, not " + what);
    if (!S_ISREG(st.st_mode)) throw FormatError(path + ": not a regular file; expected " + what);
    const std::uint64_t size = static_cast<std::uint64_t>(st.st_size);
    if (size > max_bytes)
        throw FormatError(path + ": " + human_bytes(static_cast<double>(size)) + ", larger than any " + what +
                          " (at most " + human_bytes(static_cast<double>(max_bytes)) + ")");
    const std::uint64_t avail = available_memory();
    if (avail > 0 && size > avail)
        throw FormatError(path + ": " + human_bytes(static_cast<double>(size)) + " do not fit in the " +
                          human_bytes(static_cast<double>(avail)) + " of memory available");
    std::string out(static_cast<std::size_t>(size), '\0');
    std::size_t got = 0;
    while (got < out.size()) {
        const ssize_t n = ::read(fd, &out[got], out.size() - got);
        if (n < 0) {
            if (errno == EINTR) continue;
            throw FormatError(path + ": cannot read " + what + " (" + std::strerror(errno) + ")");
        }
        if (n == 0) break;  // shrank while we read: the checks of the contents will say so
        got += static_cast<std::size_t>(n);
    }
    out.resize(got);
    return out;
}

namespace {

// `path`: the file the data are for (a full disk's error names it, not its temporary file).
void write_all(int fd, const std::string& data, const std::string& path) {
    const char* p = data.data();
    std::size_t left = data.size();
    while (left > 0) {
        const ssize_t n = ::write(fd, p, left);
        if (n < 0) {
            if (errno == EINTR) continue;  // a signal arrived (SIGINT, SIGTERM): keep writing
            throw std::runtime_error(path + ": cannot write (" + std::strerror(errno) + ")");
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
    const std::string tmpl = (slash == std::string::npos ? "" : path.substr(0, slash + 1)) + "." + base + ".XXXXXX";
    std::vector<char> name(tmpl.begin(), tmpl.end());
    name.push_back('\0');
    const int fd = ::mkstemp(name.data());
    if (fd < 0) {
        const int err = errno;
        throw std::runtime_error(path + ": cannot create a temporary file in " + dir + " (" +
                                 std::strerror(err) + ")");
    }
    const std::string tmp(name.data());
    try {
        // mkstemp creates the file 0600; give it the usual permissions (umask applies).
        const mode_t mask = ::umask(0);
        ::umask(mask);
        ::fchmod(fd, 0666 & ~mask);
        write_all(fd, data, path);
        if (::fsync(fd) != 0) throw std::runtime_error(tmp + ": fsync failed (" + std::strerror(errno) + ")");
    } catch (...) {
        ::close(fd);
        ::unlink(tmp.c_str());
        throw;
    }
    if (::close(fd) != 0) {
        const int err = errno;
        ::unlink(tmp.c_str());
        throw std::runtime_error(tmp + ": close failed (" + std::strerror(err) + ")");
    }
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
        const int err = errno;
        ::unlink(tmp.c_str());
        throw std::runtime_error(path + ": cannot replace (" + std::strerror(err) + ")");
    }
    // Make the rename itself durable.
    const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        ::fsync(dfd);
        ::close(dfd);
    }
}

namespace {

// A number from a one-line file (cgroup v2's memory.max, memory.current); 0 for "max" or none.
std::uint64_t read_number(const char* path) {
    std::ifstream in(path);
    std::string text;
    if (!(in >> text) || text == "max") return 0;
    char* end = nullptr;
    const unsigned long long v = std::strtoull(text.c_str(), &end, 10);
    return end && *end == '\0' ? static_cast<std::uint64_t>(v) : 0;
}

}  // namespace

std::uint64_t available_memory() {
    std::uint64_t avail = 0;
    std::ifstream in("/proc/meminfo");
    std::string key, unit;
    unsigned long long kb = 0;
    while (in >> key >> kb >> unit) {
        if (key == "MemAvailable:") {
            avail = static_cast<std::uint64_t>(kb) * 1024;
            break;
        }
    }
#if defined(_SC_AVPHYS_PAGES) && defined(_SC_PAGESIZE)
    if (avail == 0) {
        const long pages = ::sysconf(_SC_AVPHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
        if (pages > 0 && page > 0) avail = static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(page);
    }
#endif
    auto cap = [&](std::uint64_t limit) {
        if (limit > 0 && (avail == 0 || limit < avail)) avail = limit;
    };
    // A container's limit (cgroup v2), less what the group already uses.
    const std::uint64_t max = read_number("/sys/fs/cgroup/memory.max");
    if (max > 0) {
        const std::uint64_t used = read_number("/sys/fs/cgroup/memory.current");
        cap(max > used ? max - used : 1);
    }
    // The process's own address-space limit (ulimit -v, prlimit --as).
    struct rlimit rl {};
    if (::getrlimit(RLIMIT_AS, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY) cap(static_cast<std::uint64_t>(rl.rlim_cur));
    return avail;
}

std::string human_bytes(double bytes) {
    const char* units[] = {"bytes", "kB", "MB", "GB", "TB", "PB", "EB"};
    int u = 0;
    while (bytes >= 1000 && u < 6) bytes /= 1000, ++u;
    char buf[48];
    std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.1f %s", bytes, units[u]);
    return buf;
}

}  // namespace iwr::io
