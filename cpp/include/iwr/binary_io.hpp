// The one binary writer, reader and hash of iwr: the problem file (iwr.Problem.save), the DE engine
// state (iwr::de::State::serialize) and the iwr-engine checkpoints all use them.
//
// Every file is a sealed container (all integers little-endian, whatever the host):
//   bytes  0..7   magic (8 bytes, one per kind of file)
//   bytes  8..11  format version of that kind
//   bytes 12..15  zero
//   bytes 16..23  payload size in bytes
//   bytes 24..31  FNV-1a 64 checksum of the payload
//   bytes 32..    payload
// unseal() checks the magic, the version, the size against the bytes actually there and the
// checksum before a single payload byte is trusted; the Reader then checks every count it reads
// against the bytes left before it allocates anything, and names the field it was reading.
#pragma once

#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwr::io {

/// A malformed, truncated or foreign file. what() names the file (when known) and the field.
struct FormatError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// 64-bit FNV-1a. Each byte step is a bijection of the running state, so any change of one byte
/// changes the result; for checksums and fingerprints, not against tampering.
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

inline std::uint64_t hash64(const char* p, std::size_t n) { return Hash64().bytes(p, n).value(); }
/// 16 lower-case hex digits.
std::string hex64(std::uint64_t v);

/// Little-endian encoding, independent of the host's byte order.
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
    void doubles(const double* v, std::size_t n) {
        u64(n);
        for (std::size_t i = 0; i < n; ++i) f64(v[i]);
    }
    void doubles(const std::vector<double>& v) { doubles(v.data(), v.size()); }
    void raw(const std::string& s) { buf_ += s; }
    const std::string& data() const { return buf_; }
    std::string& data() { return buf_; }

private:
    std::string buf_;
};

/// Reads what Writer wrote. Every read names its field; a read past the end, or a count larger than
/// the bytes left could hold, throws FormatError("<context>: truncated while reading <field>")
/// before anything is allocated.
class Reader {
public:
    /// `context` starts every message (a file name and what it is).
    Reader(const char* data, std::size_t size, std::string context)
        : p_(data), n_(size), context_(std::move(context)) {}

    std::uint8_t u8(const char* field) { return static_cast<std::uint8_t>(*take(1, field)); }
    std::uint32_t u32(const char* field) {
        const char* p = take(4, field);
        std::uint32_t v = 0;
        for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(static_cast<unsigned char>(p[i])) << (8 * i);
        return v;
    }
    std::uint64_t u64(const char* field) {
        const char* p = take(8, field);
        std::uint64_t v = 0;
        for (int i = 0; i < 8; ++i) v |= static_cast<std::uint64_t>(static_cast<unsigned char>(p[i])) << (8 * i);
        return v;
    }
    std::int64_t i64(const char* field) { return static_cast<std::int64_t>(u64(field)); }
    /// An i64 that must lie in [lo, hi].
    std::int64_t i64_in(const char* field, std::int64_t lo, std::int64_t hi);
    double f64(const char* field) {
        const std::uint64_t u = u64(field);
        double v;
        std::memcpy(&v, &u, 8);
        return v;
    }
    /// A string of at most max_len bytes.
    std::string str(const char* field, std::size_t max_len = 1 << 16);
    /// A string of printable characters (no control character), at most `max_len` bytes.
    std::string text(const char* field, std::size_t max_len, bool allow_empty = true);
    /// A byte that must be 0 or 1.
    bool flag(const char* field);
    /// A count of items of `item_bytes` bytes each that must still fit in the bytes left.
    std::size_t count(const char* field, std::size_t item_bytes);
    std::vector<double> doubles(const char* field);
    /// Exactly `n` doubles (the stored count must be n).
    std::vector<double> doubles(const char* field, std::size_t n);
    std::size_t remaining() const { return n_ - i_; }
    std::size_t position() const { return i_; }
    /// Throws unless every byte was read.
    void finish();
    [[noreturn]] void fail(const std::string& what) const;

private:
    const char* take(std::size_t k, const char* field);
    const char* p_;
    std::size_t n_;
    std::size_t i_ = 0;
    std::string context_;
};

/// The sealed container of `payload` (see the top of this file).
std::string seal(const char magic[8], std::uint32_t version, const std::string& payload);

/// The payload of a sealed container, after every check of its header; `context` starts the
/// messages ("run.ckpt: "), `what` names the kind of file ("an iwr problem file").
/// Throws FormatError: "empty file", "not <what> (wrong magic bytes)", "format version V; this
/// program reads version W", "truncated: N bytes of M", "corrupt: checksum mismatch ...".
std::string unseal(const std::string& bytes, const char magic[8], std::uint32_t version,
                   const std::string& context, const char* what);
/// The same for a format that still reads its older versions: any version in [oldest, newest]
/// is accepted and stored in *version (a version outside: "format version V; this program reads
/// versions O to N").
std::string unseal(const std::string& bytes, const char magic[8], std::uint32_t oldest,
                   std::uint32_t newest, std::uint32_t* version, const std::string& context,
                   const char* what);

/// The whole of a regular file, read after checking its size: no more than `max_bytes` and no more
/// than the memory available. Refuses anything that is not a regular file (a folder, /dev/zero, a
/// pipe) at once. Throws FormatError "PATH: no such file", "PATH: not a regular file", ...
std::string read_file(const std::string& path, const char* what, std::uint64_t max_bytes);

/// Writes `data` to `path` atomically: a temporary file ".NAME.XXXXXX" in the same folder, written,
/// fsync'ed, renamed over `path`, then the folder fsync'ed. A crash leaves the old or the new file.
/// Throws std::runtime_error "PATH: problem".
void atomic_write(const std::string& path, const std::string& data);

/// Bytes of memory the system can give without swapping (MemAvailable of /proc/meminfo, else
/// free physical pages); 0 when unknown.
std::uint64_t available_memory();
/// "1.2 GB", "340 MB", ...
std::string human_bytes(double bytes);

}  // namespace iwr::io
