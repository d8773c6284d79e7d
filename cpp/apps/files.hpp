// Small file utilities of iwr-calibrate: atomic writes, a 64-bit hash, binary encoding, JSON text.
#pragma once

#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwr::app {

/// Writes `data` to `path` atomically: a temporary file in the same folder, written, fsync'ed,
/// renamed over `path`, then the folder fsync'ed. A crash leaves either the old or the new file.
/// Throws std::runtime_error "PATH: problem".
void atomic_write(const std::string& path, const std::string& data);

/// 64-bit FNV-1a. Each byte step is a bijection of the running state, so any change of one byte
/// changes the result; used for checksums and fingerprints (not against tampering).
class Hash64 {
public:
    Hash64& bytes(const void* data, std::size_t n) {
        const auto* p = static_cast<const unsigned char*>(data);
        for (std::size_t i = 0; i < n; ++i) {
            h_ ^= p[i];
            h_ *= 0x100000001b3ULL;
        }
        return *this;
    }
    Hash64& u64(std::uint64_t v) {
        unsigned char b[8];
        for (int i = 0; i < 8; ++i) b[i] = static_cast<unsigned char>(v >> (8 * i));
        return bytes(b, 8);
    }
    Hash64& f64(double v) {
        std::uint64_t u;
        std::memcpy(&u, &v, 8);
        return u64(u);
    }
    Hash64& str(const std::string& s) { return u64(s.size()).bytes(s.data(), s.size()); }
    Hash64& doubles(const double* v, std::size_t n) {
        u64(n);
        for (std::size_t i = 0; i < n; ++i) f64(v[i]);
        return *this;
    }
    std::uint64_t value() const { return h_; }

private:
    std::uint64_t h_ = 0xcbf29ce484222325ULL;
};

std::uint64_t hash64(const std::string& s);
std::string hex64(std::uint64_t v);

/// Little-endian binary encoding, independent of the host's byte order.
class Writer {
public:
    void u8(std::uint8_t v) { buf_.push_back(static_cast<char>(v)); }
    void u32(std::uint32_t v) {
        for (int i = 0; i < 4; ++i) buf_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
    }
    void u64(std::uint64_t v) {
        for (int i = 0; i < 8; ++i) buf_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
    }
    void i64(std::int64_t v) { u64(static_cast<std::uint64_t>(v)); }
    void f64(double v) {
        std::uint64_t u;
        std::memcpy(&u, &v, 8);
        u64(u);
    }
    void str(const std::string& s) {
        u64(s.size());
        buf_ += s;
    }
    void doubles(const std::vector<double>& v) {
        u64(v.size());
        for (double x : v) f64(x);
    }
    void raw(const std::string& s) { buf_ += s; }
    const std::string& data() const { return buf_; }
    std::string& data() { return buf_; }

private:
    std::string buf_;
};

/// Reads what Writer wrote; throws std::runtime_error("truncated") past the end.
class Reader {
public:
    Reader(const char* data, std::size_t size) : p_(data), n_(size) {}
    explicit Reader(const std::string& s) : Reader(s.data(), s.size()) {}
    std::uint8_t u8() { return static_cast<std::uint8_t>(*take(1)); }
    std::uint32_t u32() {
        const char* p = take(4);
        std::uint32_t v = 0;
        for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(static_cast<unsigned char>(p[i])) << (8 * i);
        return v;
    }
    std::uint64_t u64() {
        const char* p = take(8);
        std::uint64_t v = 0;
        for (int i = 0; i < 8; ++i) v |= static_cast<std::uint64_t>(static_cast<unsigned char>(p[i])) << (8 * i);
        return v;
    }
    std::int64_t i64() { return static_cast<std::int64_t>(u64()); }
    double f64() {
        const std::uint64_t u = u64();
        double v;
        std::memcpy(&v, &u, 8);
        return v;
    }
    std::string str() {
        const std::uint64_t n = u64();
        if (n > remaining()) throw std::runtime_error("truncated");
        return std::string(take(static_cast<std::size_t>(n)), static_cast<std::size_t>(n));
    }
    std::vector<double> doubles() {
        const std::uint64_t n = u64();
        if (n > remaining() / 8) throw std::runtime_error("truncated");
        std::vector<double> v(static_cast<std::size_t>(n));
        for (auto& x : v) x = f64();
        return v;
    }
    std::string raw(std::size_t n) { return std::string(take(n), n); }
    std::size_t remaining() const { return n_ - i_; }

private:
    const char* take(std::size_t k) {
        if (k > n_ - i_) throw std::runtime_error("truncated");
        const char* p = p_ + i_;
        i_ += k;
        return p;
    }
    const char* p_;
    std::size_t n_;
    std::size_t i_ = 0;
};

/// JSON text of a double that reads back to the same bits (17 significant digits); "null" for a
/// non-finite value, which JSON cannot hold.
std::string json_number(double v);
/// A JSON string literal, escaped.
std::string json_string(const std::string& s);
/// A CSV number: 17 significant digits, "inf"/"nan" as Python writes them.
std::string csv_number(double v);

// --- text as the Python package reads it ---------------------------------------------------------

/// Decodes strict UTF-8, as Python's 'utf-8' codec does (no overlong forms, surrogates or code
/// points above U+10FFFF). Returns std::string::npos when all is well, else the offset of the first
/// byte that is not valid UTF-8 (`out` then holds what came before it).
std::size_t decode_utf8(const std::string& bytes, std::u32string& out);
void append_utf8(std::string& out, char32_t cp);
std::string to_utf8(const std::u32string& s);
/// "line L, column C: byte 0xNN is not valid UTF-8", for the byte at `offset` (line and column
/// counted from 1, the column in characters).
std::string utf8_error_at(const std::string& bytes, std::size_t offset);
/// Python's str.isspace().
bool py_space(char32_t c);
/// True where Python's str.splitlines() ends a line (\r\n is one boundary: check it first).
bool py_line_break(char32_t c);
/// Python's str.strip().
std::u32string py_strip(const std::u32string& s);
/// The value of a Unicode decimal digit (category Nd, as Python's int() and float() read them),
/// else -1.
int py_decimal(char32_t c);
/// Python's float() of a str: decimal notation with optional underscores between digits, any
/// Unicode decimal digits, inf, infinity and nan in any case; false when it raises ValueError.
bool py_float(const std::u32string& s, double& out);
/// Python's repr() of a str: quoted as Python quotes it, with control and invisible characters
/// escaped, so that a message quoting a file's contents stays on one line.
std::string py_repr(const std::u32string& s);
std::string py_repr(const std::string& utf8);
/// Python's format(v, ".Ng") (the same as C's %.Ng for finite values).
std::string py_g(double v, int digits);

}  // namespace iwr::app
