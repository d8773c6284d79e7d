#include "files.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
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

namespace iwr::app {

// --- text as the Python package reads it ---------------------------------------------------------

std::size_t decode_utf8(const std::string& bytes, std::u32string& out) {
    out.clear();
    out.reserve(bytes.size());
    const std::size_t n = bytes.size();
    std::size_t i = 0;
    auto byte = [&](std::size_t k) { return static_cast<unsigned char>(bytes[k]); };
    auto cont = [&](std::size_t k) { return k < n && (byte(k) & 0xC0) == 0x80; };
    while (i < n) {
        const unsigned char b = byte(i);
        if (b < 0x80) {
            out.push_back(b);
            ++i;
            continue;
        }
        char32_t cp;
        std::size_t len;
        char32_t min;
        if (b >= 0xC2 && b <= 0xDF) {
            len = 2, cp = b & 0x1F, min = 0x80;
        } else if (b >= 0xE0 && b <= 0xEF) {
            len = 3, cp = b & 0x0F, min = 0x800;
        } else if (b >= 0xF0 && b <= 0xF4) {
            len = 4, cp = b & 0x07, min = 0x10000;
        } else {
            return i;
        }
        for (std::size_t k = 1; k < len; ++k) {
            if (!cont(i + k)) return i;
            cp = (cp << 6) | (byte(i + k) & 0x3F);
        }
        if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return i;
        out.push_back(cp);
        i += len;
    }
    return std::string::npos;
}

void append_utf8(std::string& out, char32_t cp) {
    if (cp < 0x80) {
        out += static_cast<char>(cp);
    } else if (cp < 0x800) {
        out += static_cast<char>(0xC0 | (cp >> 6));
        out += static_cast<char>(0x80 | (cp & 0x3F));
    } else if (cp < 0x10000) {
        out += static_cast<char>(0xE0 | (cp >> 12));
        out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
        out += static_cast<char>(0x80 | (cp & 0x3F));
    } else {
        out += static_cast<char>(0xF0 | (cp >> 18));
        out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
        out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
        out += static_cast<char>(0x80 | (cp & 0x3F));
    }
}

std::string to_utf8(const std::u32string& s) {
    std::string out;
    out.reserve(s.size());
    for (const char32_t c : s) append_utf8(out, c);
    return out;
}

std::string utf8_error_at(const std::string& bytes, std::size_t offset) {
    std::size_t line = 1, start = 0;
    for (std::size_t k = 0; k < offset; ++k) {
        if (bytes[k] == '\n' || (bytes[k] == '\r' && (k + 1 >= bytes.size() || bytes[k + 1] != '\n'))) {
            ++line;
            start = k + 1;
        }
    }
    std::size_t column = 1;
    for (std::size_t k = start; k < offset; ++k)
        column += (static_cast<unsigned char>(bytes[k]) & 0xC0) != 0x80;  // count lead bytes
    char hex[8];
    std::snprintf(hex, sizeof hex, "0x%02x", static_cast<unsigned>(static_cast<unsigned char>(bytes[offset])));
    return "line " + std::to_string(line) + ", column " + std::to_string(column) + ": byte " + hex +
           " is not valid UTF-8";
}

bool py_space(char32_t c) {
    return (c >= 0x09 && c <= 0x0D) || (c >= 0x1C && c <= 0x20) || c == 0x85 || c == 0xA0 ||
           c == 0x1680 || (c >= 0x2000 && c <= 0x200A) || c == 0x2028 || c == 0x2029 || c == 0x202F ||
           c == 0x205F || c == 0x3000;
}

bool py_line_break(char32_t c) {
    return c == '\n' || c == '\r' || c == 0x0B || c == 0x0C || c == 0x1C || c == 0x1D || c == 0x1E ||
           c == 0x85 || c == 0x2028 || c == 0x2029;
}

std::u32string py_strip(const std::u32string& s) {
    std::size_t b = 0, e = s.size();
    while (b < e && py_space(s[b])) ++b;
    while (e > b && py_space(s[e - 1])) --e;
    return s.substr(b, e - b);
}

int py_decimal(char32_t c) {
    // The first code point (digit zero) of each run of ten decimal digits, Unicode 14 (Python 3.11).
    static const char32_t kZeros[] = {
        0x30,    0x660,   0x6f0,   0x7c0,   0x966,   0x9e6,   0xa66,   0xae6,   0xb66,   0xbe6,
        0xc66,   0xce6,   0xd66,   0xde6,   0xe50,   0xed0,   0xf20,   0x1040,  0x1090,  0x17e0,
        0x1810,  0x1946,  0x19d0,  0x1a80,  0x1a90,  0x1b50,  0x1bb0,  0x1c40,  0x1c50,  0xa620,
        0xa8d0,  0xa900,  0xa9d0,  0xa9f0,  0xaa50,  0xabf0,  0xff10,  0x104a0, 0x10d30, 0x11066,
        0x110f0, 0x11136, 0x111d0, 0x112f0, 0x11450, 0x114d0, 0x11650, 0x116c0, 0x11730, 0x118e0,
        0x11950, 0x11c50, 0x11d50, 0x11da0, 0x16a60, 0x16ac0, 0x16b50, 0x1d7ce, 0x1d7d8, 0x1d7e2,
        0x1d7ec, 0x1d7f6, 0x1e140, 0x1e2f0, 0x1e950, 0x1fbf0};
    for (const char32_t z : kZeros)
        if (c >= z && c < z + 10) return static_cast<int>(c - z);
    return -1;
}

bool py_float(const std::u32string& s, double& out) {
    // As CPython: every Unicode decimal digit becomes its ASCII digit and every whitespace
    // character a space; anything else outside ASCII is refused.
    std::string a;
    for (const char32_t c : s) {
        const int d = py_decimal(c);
        if (d >= 0) a += static_cast<char>('0' + d);
        else if (py_space(c)) a += ' ';
        else if (c < 0x80 && c != 0) a += static_cast<char>(c);
        else return false;
    }
    std::size_t b = 0, e = a.size();
    while (b < e && std::isspace(static_cast<unsigned char>(a[b]))) ++b;
    while (e > b && std::isspace(static_cast<unsigned char>(a[e - 1]))) --e;
    a = a.substr(b, e - b);
    std::size_t i = 0;
    if (i < a.size() && (a[i] == '+' || a[i] == '-')) ++i;
    std::string word = a.substr(i);
    for (auto& ch : word) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    std::string plain;  // without the underscores
    if (word == "inf" || word == "infinity" || word == "nan") {
        plain = a;
    } else {
        auto digit = [&](std::size_t k) { return k < a.size() && a[k] >= '0' && a[k] <= '9'; };
        // digitpart: digit (["_"] digit)*
        auto digitpart = [&]() {
            if (!digit(i)) return false;
            ++i;
            for (;;) {
                if (digit(i)) ++i;
                else if (i < a.size() && a[i] == '_' && digit(i + 1)) i += 2;
                else return true;
            }
        };
        const bool whole = digitpart();
        bool frac = false;
        if (i < a.size() && a[i] == '.') {
            ++i;
            frac = digitpart();
        }
        if (!whole && !frac) return false;
        if (i < a.size() && (a[i] == 'e' || a[i] == 'E')) {
            ++i;
            if (i < a.size() && (a[i] == '+' || a[i] == '-')) ++i;
            if (!digitpart()) return false;
        }
        if (i != a.size()) return false;
        for (const char ch : a)
            if (ch != '_') plain += ch;
    }
    char* end = nullptr;
    out = std::strtod(plain.c_str(), &end);
    return !plain.empty() && end == plain.c_str() + plain.size();
}

namespace {

// Characters that Python's repr() escapes (str.isprintable() is false): control characters,
// separators other than the space, format characters, private use (an approximation of the
// Unicode tables that covers what appears in files: no unassigned code points).
bool py_unprintable(char32_t c) {
    return c < 0x20 || (c >= 0x7F && c <= 0xA0) || c == 0xAD || (c >= 0x600 && c <= 0x605) ||
           c == 0x61C || c == 0x6DD || c == 0x70F || c == 0x1680 || c == 0x180E ||
           (c >= 0x2000 && c <= 0x200F) || (c >= 0x2028 && c <= 0x202F) ||
           (c >= 0x205F && c <= 0x206F) || c == 0x3000 || (c >= 0xD800 && c <= 0xF8FF) ||
           c == 0xFEFF || (c >= 0xFFF9 && c <= 0xFFFB) || c >= 0xF0000 ||
           (c >= 0xE0000 && c <= 0xE007F);
}

}  // namespace

std::string py_repr(const std::u32string& s) {
    bool single = false, dbl = false;
    for (const char32_t c : s) {
        single = single || c == '\'';
        dbl = dbl || c == '"';
    }
    const char q = single && !dbl ? '"' : '\'';
    std::string out(1, q);
    for (const char32_t c : s) {
        if (c == static_cast<char32_t>(q) || c == '\\') {
            out += '\\';
            out += static_cast<char>(c);
        } else if (c == '\n') {
            out += "\\n";
        } else if (c == '\r') {
            out += "\\r";
        } else if (c == '\t') {
            out += "\\t";
        } else if (py_unprintable(c)) {
            char buf[16];
            if (c < 0x100) std::snprintf(buf, sizeof buf, "\\x%02x", static_cast<unsigned>(c));
            else if (c < 0x10000) std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(c));
            else std::snprintf(buf, sizeof buf, "\\U%08x", static_cast<unsigned>(c));
            out += buf;
        } else {
            append_utf8(out, c);
        }
    }
    return out + q;
}

std::string py_repr(const std::string& utf8) {
    std::u32string u;
    if (decode_utf8(utf8, u) != std::string::npos) {
        // Not UTF-8 (a caller's bug; inputs are checked first): escape every byte above ASCII.
        u.clear();
        for (const char ch : utf8) u.push_back(static_cast<unsigned char>(ch) < 0x80 ? static_cast<unsigned char>(ch) : 0xDC00u + static_cast<unsigned char>(ch));
    }
    return py_repr(u);
}

std::string py_g(double v, int digits) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    return buf;
}

}  // namespace iwr::app
