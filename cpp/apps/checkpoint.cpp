#include "checkpoint.hpp"

#include <stdexcept>

#include "files.hpp"

namespace iwr::app {

namespace {

const char kMagic[8] = {'I', 'W', 'R', 'C', 'K', 'P', 'T', '\x1a'};
constexpr std::size_t kHeaderSize = 32;

}  // namespace

std::string encode_checkpoint(const Checkpoint& c) {
    Writer p;
    p.str(c.program);
    p.u64(c.robot_fingerprint);
    p.u64(c.data_fingerprint);
    p.u64(c.settings_fingerprint);
    p.str(c.robot_file);
    p.str(c.data_file);
    p.u64(c.options.size());
    for (const auto& kv : c.options) {
        p.str(kv.first);
        p.str(kv.second);
    }
    p.str(c.engine_state);

    Writer f;
    f.raw(std::string(kMagic, 8));
    f.u32(kCheckpointVersion);
    f.u32(0);
    f.u64(p.data().size());
    f.u64(hash64(p.data()));
    f.raw(p.data());
    return f.data();
}

Checkpoint decode_checkpoint(const std::string& bytes) {
    if (bytes.size() < 8 || bytes.compare(0, 8, std::string(kMagic, 8)) != 0) {
        if (bytes.empty()) throw std::runtime_error("empty file; not an iwr-calibrate checkpoint");
        if (bytes.size() < 8 && std::string(kMagic, 8).compare(0, bytes.size(), bytes) == 0)
            throw std::runtime_error("truncated: " + std::to_string(bytes.size()) +
                                     " bytes, less than a checkpoint header");
        throw std::runtime_error("not an iwr-calibrate checkpoint (wrong magic bytes)");
    }
    if (bytes.size() < kHeaderSize)
        throw std::runtime_error("truncated: " + std::to_string(bytes.size()) +
                                 " bytes, less than a checkpoint header");
    Reader h(bytes.data() + 8, kHeaderSize - 8);
    const std::uint32_t version = h.u32();
    const std::uint32_t zero = h.u32();
    const std::uint64_t size = h.u64();
    const std::uint64_t checksum = h.u64();
    if (version != kCheckpointVersion || zero != 0)
        throw std::runtime_error("checkpoint format version " + std::to_string(version) +
                                 "; this program reads version " + std::to_string(kCheckpointVersion));
    const std::uint64_t have = bytes.size() - kHeaderSize;
    if (have < size)
        throw std::runtime_error("truncated: " + std::to_string(bytes.size()) + " bytes of " +
                                 std::to_string(size + kHeaderSize));
    if (have > size)
        throw std::runtime_error("corrupt: " + std::to_string(have - size) +
                                 " bytes after the end of the checkpoint");
    const std::string payload = bytes.substr(kHeaderSize);
    if (hash64(payload) != checksum)
        throw std::runtime_error("corrupt: checksum mismatch (the file was modified or damaged)");

    Checkpoint c;
    try {
        Reader p(payload);
        c.program = p.str();
        c.robot_fingerprint = p.u64();
        c.data_fingerprint = p.u64();
        c.settings_fingerprint = p.u64();
        c.robot_file = p.str();
        c.data_file = p.str();
        const std::uint64_t n = p.u64();
        if (n > p.remaining()) throw std::runtime_error("truncated");
        for (std::uint64_t k = 0; k < n; ++k) {
            std::string key = p.str();
            std::string value = p.str();
            c.options.emplace_back(std::move(key), std::move(value));
        }
        c.engine_state = p.str();
        if (p.remaining() != 0) throw std::runtime_error("trailing bytes");
    } catch (const std::runtime_error& e) {
        // The checksum matched, so this is a file written by another program or version.
        throw std::runtime_error(std::string("corrupt: malformed payload (") + e.what() + ")");
    }
    return c;
}

}  // namespace iwr::app
