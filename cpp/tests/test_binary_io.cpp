// C++ tests of the one binary writer/reader/hash (iwr/binary_io.hpp) and of the files built on it:
// the problem file and the engine's checkpoints. Includes the fuzzing campaign: random mutations of
// valid files, resealed with a correct checksum so that they reach the field parser, must each be
// accepted or refused with a FormatError; under -DIWR_SANITIZE=ON (.ci/run) any out-of-bounds
// read, overflow or leak aborts the test. IWR_FUZZ_ITERATIONS sets the number of mutations per
// file kind (default 3000; benchmarks/fuzz_binary_io.sh runs a longer campaign).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

#include "check.hpp"
#include "fixtures.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/checkpoint.hpp"
#include "iwr/de.hpp"
#include "iwr/forward.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"
#include "iwr/problem_file.hpp"
#include "iwr/tracker.hpp"

namespace test_binary_io {

namespace {

namespace io = iwr::io;

bool contains(const std::string& s, const std::string& needle) { return s.find(needle) != std::string::npos; }

// The message of the FormatError `fn` throws ("" if none; "OTHER: ..." for another exception).
template <class Fn>
std::string refusal(Fn fn) {
    try {
        fn();
    } catch (const io::FormatError& e) {
        return e.what();
    } catch (const std::exception& e) {
        return std::string("OTHER: ") + e.what();
    }
    return "";
}

iwr::ProblemData sample_problem(int n_poses, bool weights, const std::string& joints = "PR") {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-1, 1);
    iwr::ProblemData p;
    p.robot_name = "test robot";
    p.joint_types = joints;
    const int n = static_cast<int>(joints.size());
    p.dh = iwr::RowMatrixXd::Zero(n, 4);
    for (int i = 0; i < n; ++i) p.dh.row(i) << M_PI / 2, 10.0 * i, 300 + i, 0.1 * i;
    p.joint_limits.resize(n, 2);
    for (int i = 0; i < n; ++i) p.joint_limits.row(i) << -1000, 1000;
    for (int j = 0; j < 6; ++j) {
        const double a = j * M_PI / 3;
        p.base.row(j) << 400 * std::cos(a), 400 * std::sin(a), 0;
        p.platform.row(j) << 250 * std::cos(a + 0.3), 250 * std::sin(a + 0.3), 0;
        p.leg_offsets(j) = 600;
        p.leg_stroke.row(j) << 0, 400;
    }
    p.home_pose << 0, 0, 600, 0, 0, 0;
    p.workspace << 100, 100, 60, 0.15, 0.15, 0.15;
    p.has_measurement_joint_types = true;
    p.measurement_joint_types = joints;
    p.q.resize(n_poses, n);
    p.poses.resize(n_poses, 6);
    p.legs.resize(n_poses, 6);
    for (int k = 0; k < n_poses; ++k) {
        for (int i = 0; i < n; ++i) p.q(k, i) = 100 * u(rng);
        p.poses.row(k) << 50 * u(rng), 50 * u(rng), 600 + 50 * u(rng), 0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng);
        for (int j = 0; j < 6; ++j) p.legs(k, j) = 200 + 50 * u(rng);
    }
    if (weights) p.weights = iwr::RowMatrixXd::Constant(n_poses, 6, 2.0);
    const int np = p.n_params();
    p.lower.assign(static_cast<std::size_t>(np), -0.5);
    p.upper.assign(static_cast<std::size_t>(np), 0.5);
    p.bounds_kind = "default";
    p.x0.assign(static_cast<std::size_t>(np), 0.0);
    p.active.assign(static_cast<std::size_t>(np), true);
    for (int k = 0; k < np; ++k) p.parameter_names.push_back("p" + std::to_string(k));
    p.sources = {{"robot", "robot.toml", std::string(64, 'a')}, {"data", "data.csv", ""}};
    return p;
}

// Tracker data of the same robot: K = 3 reflectors (some unseen) or a probe, the points made by
// the objective itself at the nominal robot (so that every pose has forward kinematics).
iwr::ProblemData sample_tracker_problem(iwr::MeasurementKind kind, int n_poses = 6) {
    iwr::ProblemData p = sample_problem(n_poses, false, "PR");
    p.kind = kind;
    // A hexapod that is not architecturally singular (the planar one of sample_problem is).
    const iwr::Geometry hexapod = iwr_test::default_iwr(false);
    p.base = hexapod.base();
    p.platform = hexapod.platform();
    p.poses.resize(0, 6);
    p.weights.resize(0, 0);
    p.registration << 2000, -300, 100, 0.2, -0.1, M_PI / 2;
    // Leg readings of poses near home, so that the forward kinematics converges.
    for (int k = 0; k < n_poses; ++k) {
        iwr::Vector6d pose = p.home_pose;
        pose(0) += 10.0 * k, pose(1) -= 5.0 * k, pose(5) += 0.01 * k;
        p.legs.row(k) = (iwr::hexapod_leg_lengths(p.base, p.platform, pose) - p.leg_offsets).transpose();
    }
    if (kind == iwr::MeasurementKind::Points) {
        p.reflectors.resize(3, 3);
        p.reflectors << 100, 0, 20, -50, 80, 20, -50, -80, 20;
        p.reflector_names = {"A", "B", "C"};
    } else {
        p.probe << 10, 20, 30, 0.1, 0.2, 0.3;
        p.probe_length = 150;
    }
    p.reference = iwr::VectorXd::Zero(p.n_robot_params());
    const iwr::TrackerObjective obj(p.geometry(), p.tracker_setup(), p.q, p.legs,
                                    iwr::RowMatrixXd::Zero(n_poses, 3 * p.tracker_setup().n_points()),
                                    p.reference, p.home_pose);
    p.points = obj.predicted_points(iwr::VectorXd::Zero(obj.n_params()));
    if (kind == iwr::MeasurementKind::Points) {
        p.points.block(1, 3, 1, 3).setConstant(NAN);  // reflector B not seen at pose 1
    } else {
        p.probe_poses = iwr::RowMatrixXd::Constant(n_poses, 6, 0.5);
    }
    const int np = p.n_params();
    p.lower.assign(static_cast<std::size_t>(np), -0.5);
    p.upper.assign(static_cast<std::size_t>(np), 0.5);
    p.x0.assign(static_cast<std::size_t>(np), 0.0);
    p.x0.back() = 0.25;
    p.active.assign(static_cast<std::size_t>(np), true);
    p.active[3] = false;
    p.parameter_names.clear();
    for (int k = 0; k < np; ++k) p.parameter_names.push_back("p" + std::to_string(k));
    return p;
}

bool same_problem(const iwr::ProblemData& a, const iwr::ProblemData& b) {
    return a.robot_name == b.robot_name && a.joint_types == b.joint_types && a.dh == b.dh &&
           a.joint_limits == b.joint_limits && a.base == b.base && a.platform == b.platform &&
           a.leg_offsets == b.leg_offsets && a.leg_stroke == b.leg_stroke && a.home_pose == b.home_pose &&
           a.workspace == b.workspace && a.q == b.q && a.poses == b.poses && a.legs == b.legs &&
           a.weights == b.weights && a.lower == b.lower && a.upper == b.upper &&
           a.bounds_kind == b.bounds_kind && a.parameter_names == b.parameter_names &&
           a.measurement_joint_types == b.measurement_joint_types && a.sources.size() == b.sources.size() &&
           a.sources[0].sha256 == b.sources[0].sha256 && a.sources[1].path == b.sources[1].path &&
           a.kind == b.kind && a.registration == b.registration && a.reflectors == b.reflectors &&
           a.reflector_names == b.reflector_names && a.probe == b.probe && a.probe_length == b.probe_length &&
           a.probe_poses == b.probe_poses && a.reference == b.reference && a.x0 == b.x0 && a.active == b.active &&
           // NaN != NaN: the points compared bit for bit
           a.points.size() == b.points.size() &&
           (a.points.size() == 0 ||
            std::memcmp(a.points.data(), b.points.data(), sizeof(double) * static_cast<std::size_t>(a.points.size())) == 0);
}

// The same container header around another payload, with its size and checksum recomputed.
std::string reseal(const std::string& file, const std::string& payload) {
    io::Writer w;
    w.raw(file.substr(0, 16));
    w.u64(payload.size());
    w.u64(io::hash64(payload.data(), payload.size()));
    w.raw(payload);
    return w.data();
}

int fuzz_iterations() {
    const char* env = std::getenv("IWR_FUZZ_ITERATIONS");
    return env ? std::max(1, std::atoi(env)) : 3000;
}

// Random mutations of the payload of `good`, resealed; each must be accepted or refused with a
// FormatError. Returns the number refused; counts anything else as a failure.
template <class Decode>
int fuzz(const std::string& good, Decode decode, const char* what, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    const std::string payload = good.substr(32);
    const int iterations = fuzz_iterations();
    int refused = 0, accepted = 0, other = 0;
    for (int t = 0; t < iterations; ++t) {
        std::string m = payload;
        const int edits = 1 + static_cast<int>(rng() % 4);
        for (int e = 0; e < edits && !m.empty(); ++e) {
            const std::size_t at = rng() % m.size();
            switch (rng() % 6) {
                case 0: m[at] = static_cast<char>(m[at] ^ (1 << (rng() % 8))); break;  // a bit
                case 1: m[at] = static_cast<char>(rng()); break;                         // a byte
                case 2: {  // a 64-bit count or value: 0, -1, huge, or a NaN's bits
                    const std::uint64_t vals[] = {0, ~0ULL, 1ULL << 62, 0x7ff8000000000001ULL, 0xfff0000000000000ULL,
                                                  static_cast<std::uint64_t>(-5)};
                    const std::uint64_t v = vals[rng() % 6];
                    for (int k = 0; k < 8 && at + static_cast<std::size_t>(k) < m.size(); ++k)
                        m[at + static_cast<std::size_t>(k)] = static_cast<char>(v >> (8 * k));
                    break;
                }
                case 3: m.resize(at); break;                                               // cut
                case 4: m.insert(at, std::string(1 + rng() % 16, static_cast<char>(rng()))); break;
                default: m.erase(at, 1 + rng() % 16); break;
            }
        }
        const std::string msg = refusal([&] { decode(reseal(good, m)); });
        if (msg.empty()) ++accepted;
        else if (contains(msg, "OTHER: ")) {
            ++other;
            if (other < 5) std::fprintf(stderr, "%s: not a FormatError: %s\n", what, msg.c_str());
        } else ++refused;
    }
    std::printf("fuzz %s: %d mutations, %d refused with a message, %d accepted, %d other errors, 0 crashes\n",
                what, iterations, refused, accepted, other);
    CHECK(other == 0);
    return refused;
}

IWR_TEST(hash_and_hex) {
    CHECK(io::hash64("", 0) == 0xcbf29ce484222325ULL);
    CHECK(io::hash64("a", 1) == 0xaf63dc4c8601ec8cULL);  // the published FNV-1a 64 test vector
    CHECK(io::hex64(255) == "00000000000000ff");
    CHECK(io::human_bytes(25.3e9) == "25.3 GB");
}

IWR_TEST(reader_checks_counts_before_allocating) {
    io::Writer w;
    w.u64(1ULL << 60);  // a count of doubles no file holds
    w.f64(1.0);
    io::Reader r(w.data().data(), w.data().size(), "x.bin: ");
    const std::string msg = refusal([&] { r.doubles("population"); });
    CHECK(contains(msg, "x.bin: truncated or corrupt: population says 1152921504606846976 items"));
    io::Reader r2(w.data().data(), 4, "x.bin: ");
    CHECK(contains(refusal([&] { r2.u64("seed"); }), "x.bin: truncated while reading seed"));
    io::Writer s;
    s.str(std::string(100, 'a'));
    io::Reader r3(s.data().data(), s.data().size(), "");
    CHECK(contains(refusal([&] { r3.str("name", 10); }), "name is 100 bytes long, more than 10"));
    io::Writer v;
    v.i64(-5);
    io::Reader r4(v.data().data(), v.data().size(), "");
    CHECK(contains(refusal([&] { r4.i64_in("generations", -1, 100); }), "generations is -5, outside [-1, 100]"));
}

IWR_TEST(container_refuses_damage) {
    const char magic[8] = {'T', 'E', 'S', 'T', 'M', 'A', 'G', '\x1a'};
    const std::string good = io::seal(magic, 3, "some payload bytes");
    CHECK(io::unseal(good, magic, 3, "f: ", "a test file") == "some payload bytes");
    int refused = 0;
    for (std::size_t n = 0; n < good.size(); ++n)
        refused += !refusal([&] { io::unseal(good.substr(0, n), magic, 3, "f: ", "a test file"); }).empty();
    CHECK(refused == static_cast<int>(good.size()));
    refused = 0;
    int total = 0;
    for (std::size_t i = 0; i < good.size(); ++i)
        for (int bit = 0; bit < 8; ++bit, ++total) {
            std::string bad = good;
            bad[i] = static_cast<char>(bad[i] ^ (1 << bit));
            refused += !refusal([&] { io::unseal(bad, magic, 3, "f: ", "a test file"); }).empty();
        }
    CHECK(refused == total);
    CHECK(contains(refusal([&] { io::unseal(good, magic, 4, "f: ", "a test file"); }),
                   "f: format version 3; this program reads version 4"));
    CHECK(contains(refusal([&] { io::unseal("hello world, not it", magic, 3, "f: ", "a test file"); }),
                   "f: not a test file (wrong magic bytes)"));
    CHECK(contains(refusal([&] { io::unseal(good + "x", magic, 3, "f: ", "a test file"); }), "1 bytes after the end"));
    // A header claiming 2^64 - 1 bytes: refused from the length, nothing allocated.
    std::string huge = good.substr(0, 32);
    for (int k = 0; k < 8; ++k) huge[16 + static_cast<std::size_t>(k)] = '\xff';
    CHECK(contains(refusal([&] { io::unseal(huge, magic, 3, "f: ", "a test file"); }), "truncated"));
}

IWR_TEST(read_file_refuses_what_is_not_a_file) {
    const auto t0 = std::chrono::steady_clock::now();
    CHECK(contains(refusal([] { io::read_file("/dev/zero", "a checkpoint", 1 << 30); }),
                   "/dev/zero: not a regular file"));
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5));  // not 2 GB read first
    CHECK(contains(refusal([] { io::read_file("/", "a checkpoint", 1 << 30); }), "/: is a folder"));
    CHECK(contains(refusal([] { io::read_file("/nonexistent/x.ckpt", "a checkpoint", 1 << 30); }),
                   "/nonexistent/x.ckpt: no such file"));
    char name[] = "/tmp/iwr_io_testXXXXXX";
    const int fd = ::mkstemp(name);
    CHECK(fd >= 0);
    CHECK(::write(fd, "0123456789", 10) == 10);
    ::close(fd);
    CHECK(io::read_file(name, "a test file", 10) == "0123456789");
    CHECK(contains(refusal([&] { io::read_file(name, "a test file", 9); }), "larger than any a test file"));
    io::atomic_write(name, "new");
    CHECK(io::read_file(name, "a test file", 10) == "new");
    ::unlink(name);
}

IWR_TEST(problem_round_trip) {
    for (const std::string joints : {"", "PR", "PPRR"}) {
        for (bool weights : {false, true}) {
            const iwr::ProblemData p = sample_problem(5, weights, joints);
            const std::string bytes = iwr::encode_problem(p);
            const iwr::ProblemData q = iwr::decode_problem(bytes, "p.iwrp: ");
            CHECK(same_problem(p, q));
            CHECK(q.robot_fingerprint() == p.robot_fingerprint() && q.data_fingerprint() == p.data_fingerprint());
            CHECK(iwr::encode_problem(q) == bytes);  // deterministic
            // The objective it describes can be built and evaluated.
            iwr::Objective obj(q.geometry(), q.q, q.poses, q.legs, q.weights);
            CHECK(std::isfinite(obj.cost(iwr::VectorXd::Zero(q.n_params()))));
        }
    }
    iwr::ProblemData other = sample_problem(5, false);
    other.legs(0, 0) += 1e-3;
    CHECK(other.data_fingerprint() != sample_problem(5, false).data_fingerprint());
}

// Whether the writer refuses `p` after `edit` with a message holding `needle`.
template <class Edit>
bool encode_refused(iwr::ProblemData p, Edit edit, const std::string& needle) {
    edit(p);
    try {
        iwr::encode_problem(p);
    } catch (const std::invalid_argument& e) {
        if (contains(e.what(), needle)) return true;
        std::fprintf(stderr, "message without '%s': %s\n", needle.c_str(), e.what());
        return false;
    }
    std::fprintf(stderr, "accepted; expected '%s'\n", needle.c_str());
    return false;
}

IWR_TEST(tracker_problem_round_trip) {
    for (auto kind : {iwr::MeasurementKind::Points, iwr::MeasurementKind::Probe}) {
        const iwr::ProblemData p = sample_tracker_problem(kind);
        const std::string bytes = iwr::encode_problem(p);
        const iwr::ProblemData q = iwr::decode_problem(bytes, "t.iwrp: ");
        CHECK(same_problem(p, q));
        CHECK(q.n_params() == q.n_robot_params() + (kind == iwr::MeasurementKind::Points ? 15 : 12));
        CHECK(q.n_active() == q.n_params() - 1);
        CHECK(iwr::encode_problem(q) == bytes);
        CHECK(q.robot_fingerprint() == p.robot_fingerprint() && q.data_fingerprint() == p.data_fingerprint());
        // Not the fingerprints of the same robot's leg data, nor of the other kind.
        CHECK(q.robot_fingerprint() != sample_problem(6, false).robot_fingerprint());
        // The objective it describes: zero cost at the nominal (the points were made there).
        const iwr::TrackerObjective obj(q.geometry(), q.tracker_setup(), q.q, q.legs, q.points, q.reference,
                                        q.home_pose);
        CHECK(obj.cost(iwr::VectorXd::Zero(q.n_params())) < 1e-18);
        // The search start is part of the problem's identity (a checkpoint of another is refused).
        iwr::ProblemData other = p;
        other.active[3] = true;
        CHECK(other.robot_fingerprint() != p.robot_fingerprint());
        other = p;
        other.points(0, 0) += 1e-9;
        CHECK(other.data_fingerprint() != p.data_fingerprint());
    }
    CHECK(sample_tracker_problem(iwr::MeasurementKind::Points).robot_fingerprint() !=
          sample_tracker_problem(iwr::MeasurementKind::Probe).robot_fingerprint());
}

IWR_TEST(tracker_problem_refuses_bad_values) {
    auto refused_with = [](iwr::MeasurementKind kind, auto edit, const std::string& needle) {
        return encode_refused(sample_tracker_problem(kind), edit, needle);
    };
    const auto points = iwr::MeasurementKind::Points, probe = iwr::MeasurementKind::Probe;
    CHECK(refused_with(points, [](auto& p) { p.points(2, 4) = NAN; }, "points: row 2, reflector 2 has some coordinates NaN"));
    CHECK(refused_with(points, [](auto& p) { p.points(2, 4) = INFINITY; }, "points: row 2, column 4 is inf, not finite"));
    CHECK(refused_with(points, [](auto& p) { p.points.setConstant(NAN); }, "points: no reflector is seen"));
    CHECK(refused_with(probe, [](auto& p) { p.points(1, 1) = NAN; }, "points: row 1, column 1 is nan, not finite"));
    CHECK(refused_with(points, [](auto& p) { p.reflector_names[2] = "A"; }, "reflector name: 'A' given twice"));
    CHECK(refused_with(points, [](auto& p) { p.reflector_names[2] = ""; }, "reflector name"));
    CHECK(refused_with(points, [](auto& p) { p.reflectors(1, 2) = NAN; }, "reflectors: row 1, column 2 is nan"));
    CHECK(refused_with(points, [](auto& p) { p.registration(4) = NAN; }, "registration: row 4, column 0 is nan"));
    CHECK(refused_with(probe, [](auto& p) { p.probe_length = 0; }, "probe length: 0"));
    CHECK(refused_with(probe, [](auto& p) { p.probe_length = NAN; }, "probe length: nan"));
    CHECK(refused_with(probe, [](auto& p) { p.probe_poses(0, 5) = NAN; }, "probe poses: row 0, column 5 is nan"));
    CHECK(refused_with(probe, [](auto& p) { p.reference(7) = NAN; }, "reference: row 7, column 0 is nan"));
    CHECK(refused_with(points, [](auto& p) { p.x0[2] = NAN; }, "x0: parameter 2 is nan, not finite"));
    CHECK(refused_with(points, [](auto& p) { p.active.assign(p.active.size(), false); }, "active: no parameter is active"));
    CHECK(refused_with(points, [](auto& p) { p.active.pop_back(); }, "active: 64 flags; expected 65"));
    CHECK(refused_with(points, [](auto& p) { p.lower.pop_back(), p.upper.pop_back(); }, "lower bounds"));
    CHECK(refused_with(probe, [](auto& p) { p.parameter_names.pop_back(); }, "parameter names: 61; expected 62"));
    // A file whose kind byte is not 0, 1, 2 or 3.
    const std::string good = iwr::encode_problem(sample_tracker_problem(points));
    io::Reader r(good.data() + 32, good.size() - 32, "");
    (void)r.text("", 4096), (void)r.str("", 64);
    for (int k = 0; k < 8; ++k) (void)r.doubles("");
    (void)r.u8(""), (void)r.str("", 64);
    std::string payload = good.substr(32);
    payload[r.position()] = 7;
    CHECK(contains(refusal([&] { iwr::decode_problem(reseal(good, payload), "t.iwrp: "); }),
                   "t.iwrp: measurement kind: 7; expected 0 (pose in {0}), 1 (points in {T}), 2 (probe pose in "
                   "{T}) or, from version 4, 3 (ballbar distances)"));
}

IWR_TEST(problem_refuses_bad_values) {
    auto refused_with = [](auto edit, const std::string& needle) {
        return encode_refused(sample_problem(4, true), edit, needle);
    };
    CHECK(refused_with([](auto& p) { p.poses(2, 1) = NAN; }, "poses: row 2, column 1 is nan, not finite"));
    CHECK(refused_with([](auto& p) { p.legs(0, 3) = 1e308; }, "legs: row 0, column 3"));
    CHECK(refused_with([](auto& p) { p.weights(1, 1) = -1; }, "weights: row 1, column 1 is negative"));
    CHECK(refused_with([](auto& p) { p.lower[3] = 1; }, "bounds: parameter 3"));
    CHECK(refused_with([](auto& p) { p.parameter_names.pop_back(); }, "parameter names: 49; expected 50"));
    CHECK(refused_with([](auto& p) { p.joint_types = "PX"; }, "joint types: 'X'"));
    CHECK(refused_with([](auto& p) { p.bounds_kind = "wide"; }, "bounds kind: 'wide'"));
    CHECK(refused_with([](auto& p) { p.parameter_names[0] = "a\nb"; }, "parameter name: holds a control character"));
    // Text is UTF-8 (Python decodes it so): a stray byte, an overlong form, a surrogate, a cut
    // sequence are refused naming the field.
    CHECK(refused_with([](auto& p) { p.parameter_names[0] = "a\xcd"; }, "parameter name: not valid UTF-8 text (byte 1)"));
    CHECK(refused_with([](auto& p) { p.parameter_names[0] = "\xc0\xaf"; }, "parameter name: not valid UTF-8"));
    CHECK(refused_with([](auto& p) { p.parameter_names[0] = "\xed\xa0\x80"; }, "parameter name: not valid UTF-8"));
    CHECK(refused_with([](auto& p) { p.parameter_names[0] = "x\xe2\x82"; }, "parameter name: not valid UTF-8"));
    CHECK(refused_with([](auto& p) { p.leg_stroke(2, 0) = 500; }, "leg stroke: leg 3"));
    CHECK(refused_with([](auto& p) { p.measurement_joint_types = "RR"; }, "do not match the robot's"));
    CHECK(refused_with([](auto& p) { p.sources[0].sha256 = "xyz"; }, "source sha256"));
    CHECK(refused_with(
              [](auto& p) {
                  p.q.resize(0, 2), p.poses.resize(0, 6), p.legs.resize(0, 6), p.weights.resize(0, 6);
              },
              "number of poses: 0"));
}

// The sample problem of each kind, weighted by a random lower-triangular whitening.
iwr::ProblemData sample_weighted_problem(iwr::MeasurementKind kind) {
    iwr::ProblemData p = kind == iwr::MeasurementKind::Pose ? sample_problem(5, true) : sample_tracker_problem(kind);
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-1, 1);
    const int m = p.residuals_per_pose();
    p.whitening = iwr::RowMatrixXd::Zero(p.n_poses(), m * m);
    for (int k = 0; k < p.n_poses(); ++k)
        for (int i = 0; i < m; ++i)
            for (int j = 0; j <= i; ++j) p.whitening(k, i * m + j) = (i == j ? 3.0 : 0.0) + u(rng);
    p.weighting = "a test whitening";
    return p;
}

// sum_k |W_k r_k|^2 of unweighted residuals r, written out.
double whitened(const iwr::RowMatrixXd& w, const iwr::VectorXd& r) {
    const int n = static_cast<int>(w.rows()), m = static_cast<int>(r.size()) / n;
    double cost = 0;
    for (int k = 0; k < n; ++k)
        for (int i = 0; i < m; ++i) {
            double s = 0;
            for (int j = 0; j < m; ++j) s += w(k, i * m + j) * r(k * m + j);
            cost += s * s;
        }
    return cost;
}

IWR_TEST(weighted_problem_round_trip_and_objective) {
    static_assert(iwr::is_objective_v<iwr::Objective> && iwr::is_objective_v<iwr::TrackerObjective> &&
                      iwr::is_objective_v<iwr::EffectObjective> &&
                      !iwr::is_objective_v<int>,
                  "the built-in objectives meet the requirements of iwr/measurement_kind.hpp");
    for (auto kind : {iwr::MeasurementKind::Pose, iwr::MeasurementKind::Points, iwr::MeasurementKind::Probe}) {
        const iwr::ProblemData p = sample_weighted_problem(kind);
        const std::string bytes = iwr::encode_problem(p);
        const iwr::ProblemData q = iwr::decode_problem(bytes, "w.iwrp: ");
        CHECK(same_problem(p, q) && q.version == iwr::kProblemVersion && q.weighted());
        CHECK(q.whitening == p.whitening && q.weighting == p.weighting);
        CHECK(iwr::encode_problem(q) == bytes);
        // Weighted is another problem of the same data.
        iwr::ProblemData plain = p;
        plain.whitening.resize(0, 0);
        CHECK(plain.robot_fingerprint() != q.robot_fingerprint());
        CHECK(plain.data_fingerprint() == q.data_fingerprint());
        iwr::ProblemData other = p;
        other.whitening(1, 0) += 1e-9;
        CHECK(other.robot_fingerprint() != q.robot_fingerprint());
        // The engine's objective of the file: the whitened cost of the unweighted residuals (for
        // leg data without the leg weights: they are folded into the whitening).
        const iwr::AnyObjective obj = iwr::make_objective(q);
        CHECK(obj.index() == (kind == iwr::MeasurementKind::Pose ? 0u : 1u));
        std::mt19937_64 rng(3);
        std::uniform_real_distribution<double> u(-0.05, 0.05);
        for (int t = 0; t < 5; ++t) {
            iwr::VectorXd x(q.n_params());
            for (int i = 0; i < x.size(); ++i) x(i) = u(rng);
            iwr::VectorXd r;
            if (kind == iwr::MeasurementKind::Pose) {
                r = iwr::Objective(q.geometry(), q.q, q.poses, q.legs).residuals(x);
            } else {
                r = iwr::TrackerObjective(q.geometry(), q.tracker_setup(), q.q, q.legs, q.points, q.reference,
                                          q.home_pose)
                        .residuals(x);
            }
            const double expected = whitened(q.whitening, r);
            const double cost = std::visit([&](const auto& o) { return o.cost(x); }, obj);
            CHECK(std::fabs(cost - expected) <= 1e-12 * expected);
            const auto failures = std::visit([&](const auto& o) { return iwr::objective_failures(o, x); }, obj);
            CHECK(failures.empty());
        }
    }
    // What the reader refuses of a weighting.
    auto refused_with = [](auto edit, const std::string& needle) {
        return encode_refused(sample_weighted_problem(iwr::MeasurementKind::Points), edit, needle);
    };
    CHECK(refused_with([](auto& p) { p.whitening(2, 1) = 0.5; }, "whitening: pose 2, entry (0, 1) is 0.5"));
    CHECK(refused_with([](auto& p) { p.whitening(4, 9) = NAN; }, "whitening: row 4, column 9 is nan, not finite"));
    CHECK(refused_with([](auto& p) { p.weighting = "a\nb"; }, "weighting: holds a control character"));
    const std::string weighted = iwr::encode_problem(sample_weighted_problem(iwr::MeasurementKind::Probe));
    CHECK(fuzz(weighted, [](const std::string& b) { iwr::decode_problem(b, "fuzz.iwrp: "); },
               "weighted problem file", 2) > 0);
}

IWR_TEST(version_2_and_3_files_read_as_before) {
    // A version 3 file: a version 4 file of a problem without effects without its (empty) effects
    // section (the 33 bytes before the bounds: no effect, no payload, no temperature), sealed as
    // version 3; a version 2 file: that without the weighted flag (the byte before), as version 2.
    for (auto kind : {iwr::MeasurementKind::Pose, iwr::MeasurementKind::Points, iwr::MeasurementKind::Probe}) {
        const iwr::ProblemData p = kind == iwr::MeasurementKind::Pose ? sample_problem(5, true)
                                                                      : sample_tracker_problem(kind);
        const std::string v4 = iwr::encode_problem(p);
        io::Writer tail;
        tail.doubles(p.lower);
        tail.doubles(p.upper);
        tail.str(p.bounds_kind);
        tail.doubles(p.x0);
        tail.u64(p.active.size());
        for (bool a : p.active) tail.u8(a ? 1 : 0);
        tail.u64(p.parameter_names.size());
        for (const auto& n : p.parameter_names) tail.str(n);
        tail.u64(p.sources.size());
        for (const auto& src : p.sources) tail.str(src.role), tail.str(src.path), tail.str(src.sha256);
        io::Writer no_effects;
        no_effects.u64(0), no_effects.u8(0), no_effects.u64(0), no_effects.u64(0), no_effects.u64(0);
        std::string payload = v4.substr(32);
        const std::size_t effects = payload.size() - tail.data().size() - no_effects.data().size();
        CHECK(payload.compare(effects, std::string::npos, no_effects.data() + tail.data()) == 0);
        payload.erase(effects, no_effects.data().size());
        const std::string v3 = io::seal(v4.substr(0, 8).c_str(), 3, payload);
        const std::size_t flag = effects - 1;
        CHECK(payload[flag] == 0);
        std::string payload2 = payload;
        payload2.erase(flag, 1);
        const std::string v2 = io::seal(v4.substr(0, 8).c_str(), 2, payload2);
        const iwr::ProblemData q = iwr::decode_problem(v2, "old.iwrp: ");
        const iwr::ProblemData q3 = iwr::decode_problem(v3, "v3.iwrp: ");
        const iwr::ProblemData q4 = iwr::decode_problem(v4, "new.iwrp: ");
        CHECK(q.version == 2 && q3.version == 3 && q4.version == 4 && !q.weighted() && same_problem(q, q3) &&
              same_problem(q3, q4) && q4.effects.empty());
        CHECK(q.robot_fingerprint() == q3.robot_fingerprint() && q.data_fingerprint() == q3.data_fingerprint());
        CHECK(q4.robot_fingerprint() == q3.robot_fingerprint() && q4.data_fingerprint() == q3.data_fingerprint());
        // The same objective, bit for bit.
        const iwr::AnyObjective a = iwr::make_objective(q), b = iwr::make_objective(q3), c = iwr::make_objective(q4);
        const iwr::VectorXd x = iwr::VectorXd::Constant(q.n_params(), 0.01);
        const auto cost = [&](const iwr::AnyObjective& o) { return std::visit([&](const auto& f) { return f.cost(x); }, o); };
        CHECK(cost(a) == cost(b) && cost(b) == cost(c));
        // A version 2 payload read as version 3 would be misaligned: the version decides.
        CHECK(!refusal([&] { iwr::decode_problem(reseal(v3, payload2), "mixed.iwrp: "); }).empty());
    }
}

IWR_TEST(problem_fuzz) {
    const std::string good = iwr::encode_problem(sample_problem(6, true));
    const int refused = fuzz(good, [](const std::string& b) { iwr::decode_problem(b, "fuzz.iwrp: "); },
                             "problem file", 1);
    CHECK(refused > 0);
    for (auto kind : {iwr::MeasurementKind::Points, iwr::MeasurementKind::Probe}) {
        const std::string tracker = iwr::encode_problem(sample_tracker_problem(kind));
        CHECK(fuzz(tracker, [](const std::string& b) { iwr::decode_problem(b, "fuzz.iwrp: "); },
                   "tracker problem file", 1) > 0);
    }
}

// A tiny DE run's checkpoint.
class Sphere : public iwr::de::BatchFunction {
public:
    int dim() const override { return 5; }
    void evaluate(const double* X, std::size_t m, double* out, iwr::ThreadPool&) override {
        for (std::size_t i = 0; i < m; ++i) {
            double s = 0;
            for (int j = 0; j < 5; ++j) s += X[i * 5 + static_cast<std::size_t>(j)] * X[i * 5 + static_cast<std::size_t>(j)];
            out[i] = s;
        }
    }
};

iwr::Checkpoint sample_checkpoint() {
    iwr::de::Settings s;
    s.strategy = iwr::de::Strategy::shade;
    s.lower.assign(5, -1.0);
    s.upper.assign(5, 1.0);
    s.population_size = 8;
    s.memory_size = 3;
    Sphere f;
    iwr::ThreadPool pool(1);
    iwr::Checkpoint c;
    c.state = iwr::de::init(s, f, pool);
    for (int g = 0; g < 3; ++g) iwr::de::step(c.state, f, pool);
    c.program = "test";
    c.robot_fingerprint = 1;
    c.data_fingerprint = 2;
    c.settings_fingerprint = 3;
    c.problem_file = "p.iwrp";
    c.generations = 10;
    c.target_cost = 1e-4;
    c.tol = 0.01;
    c.stagnation_generations = 20;
    c.stagnation_tol = 1e-6;
    c.checkpoint_every = 5;
    c.success = false;
    c.message = "checkpoint";
    const iwr::VectorXd x = c.state.best_x();
    // x: every parameter; the state searched parameters 0..4 of 7 (two held at x0 = 0.25).
    c.x.assign(x.data(), x.data() + x.size());
    c.x.push_back(0.25);
    c.x.push_back(0.25);
    c.active = {0, 1, 2, 3, 4};
    c.fun = c.state.best_cost();
    return c;
}

IWR_TEST(checkpoint_round_trip_and_damage) {
    const iwr::Checkpoint c = sample_checkpoint();
    const std::string bytes = iwr::encode_checkpoint(c, c.state);
    const iwr::Checkpoint back = iwr::decode_checkpoint(bytes, "c.ckpt: ");
    CHECK(back.robot_fingerprint == 1 && back.data_fingerprint == 2 && back.settings_fingerprint == 3);
    CHECK(back.generations == 10 && !back.max_evaluations && back.target_cost == 1e-4);
    CHECK(back.tol == 0.01 && back.atol == 0 && back.stagnation_generations == 20 &&
          back.stagnation_tol == 1e-6);
    CHECK(back.x == c.x && back.fun == c.fun && back.message == "checkpoint" && !back.success);
    CHECK(back.active == c.active);
    CHECK(back.state.generation == 3 && back.state.population == c.state.population);
    int refused = 0, total = 0;
    for (std::size_t n = 0; n < bytes.size(); n += 7, ++total)
        refused += !refusal([&] { iwr::decode_checkpoint(bytes.substr(0, n), ""); }).empty();
    CHECK(refused == total);
}

IWR_TEST(checkpoint_of_version_3_is_read_with_the_tests_off) {
    // A version 3 checkpoint: version 4's payload without its four convergence fields (found as
    // the bytes where two checkpoints that differ only in them differ), sealed as version 3.
    iwr::Checkpoint c = sample_checkpoint();
    const std::string with = iwr::encode_checkpoint(c, c.state);
    c.tol = 0.5, c.atol = 0.25, c.stagnation_generations = 7, c.stagnation_tol = 0.125;
    const std::string other = iwr::encode_checkpoint(c, c.state);
    const std::size_t header = 32;
    std::size_t at = header;
    while (at < with.size() && with[at] == other[at]) ++at;  // tol's lowest byte (0.01 against 0.5)
    std::string payload = with.substr(header);
    const std::size_t from = at - header;
    CHECK(from + 32 <= payload.size());
    payload.erase(from, 32);
    io::Writer w;
    w.raw(with.substr(0, 8));
    w.u32(3);
    w.u32(0);
    w.u64(payload.size());
    w.u64(io::hash64(payload.data(), payload.size()));
    w.raw(payload);
    const iwr::Checkpoint back = iwr::decode_checkpoint(w.data(), "v3.ckpt: ");
    CHECK(back.tol == 0 && back.atol == 0 && back.stagnation_generations == 0 && back.stagnation_tol == 0);
    CHECK(back.generations == 10 && back.target_cost == 1e-4 && back.checkpoint_every == 5);
    CHECK(back.x == sample_checkpoint().x && back.state.generation == 3);
    // Version 2 is refused by its version.
    std::string v2 = w.data();
    v2[8] = 2;
    CHECK(contains(refusal([&] { iwr::decode_checkpoint(v2, "v2.ckpt: "); }), "version"));
}

IWR_TEST(checkpoint_fields_are_range_checked) {
    // Crafted checkpoints, checksums recomputed: each field as if a user had typed it.
    auto refused_with = [](auto edit, const std::string& needle) {
        iwr::Checkpoint c = sample_checkpoint();
        edit(c);
        const std::string msg = refusal([&] { iwr::decode_checkpoint(iwr::encode_checkpoint(c, c.state), "c.ckpt: "); });
        if (!contains(msg, needle)) std::fprintf(stderr, "expected '%s', got '%s'\n", needle.c_str(), msg.c_str());
        return contains(msg, needle) && !contains(msg, "OTHER");
    };
    CHECK(refused_with([](auto& c) { c.generations = -5; }, "c.ckpt: generations is -5, outside [-1,"));
    CHECK(refused_with([](auto& c) { c.checkpoint_every = -1; }, "checkpoint every is -1"));
    CHECK(refused_with([](auto& c) { c.target_cost = INFINITY; }, "target cost is not finite"));
    CHECK(refused_with([](auto& c) { c.tol = -1; }, "c.ckpt: tol is not a finite number >= 0"));
    CHECK(refused_with([](auto& c) { c.atol = NAN; }, "atol is not a finite number >= 0"));
    CHECK(refused_with([](auto& c) { c.stagnation_generations = -3; }, "stagnation generations is -3"));
    CHECK(refused_with([](auto& c) { c.stagnation_tol = INFINITY; }, "stagnation tol is not a finite"));
    CHECK(refused_with([](auto& c) { c.active.push_back(6); }, "active: 6 parameters; the engine state has 5"));
    CHECK(refused_with([](auto& c) { c.active[2] = 7; }, "active is 7, outside [2, 6]"));
    CHECK(refused_with([](auto& c) { c.active[3] = 1; }, "active is 1, outside [3, 6]"));  // not increasing
    CHECK(refused_with([](auto& c) { c.x[0] = 7; }, "x: parameter 0 is outside the bounds"));
    CHECK(refused_with([](auto& c) { c.active[4] = 6, c.x[6] = 7; }, "x: parameter 6 is outside the bounds"));
    CHECK(refused_with([](auto& c) { c.x[5] = NAN; }, "x: parameter 5 is not finite"));
    CHECK(refused_with([](auto& c) { c.success = true, c.fun = NAN; }, "success with a cost that is not finite"));
    CHECK(refused_with([](auto& c) { c.problem_file = "a\nb"; }, "problem file: holds a control character"));
    CHECK(refused_with([](auto& c) { c.state.generation = -2; }, "corrupt engine state"));
    CHECK(refused_with([](auto& c) { c.state.np = 100000; }, "corrupt engine state"));
    // Unknown trailing fields (a key this version does not know) are refused.
    const std::string good = iwr::encode_checkpoint(sample_checkpoint(), sample_checkpoint().state);
    io::Writer extra;
    extra.str("output");
    extra.str("/etc/passwd");
    CHECK(contains(refusal([&] { iwr::decode_checkpoint(reseal(good, good.substr(32) + extra.data()), ""); }),
                   "unexpected bytes at the end"));
}

IWR_TEST(checkpoint_fuzz) {
    const std::string good = iwr::encode_checkpoint(sample_checkpoint(), sample_checkpoint().state);
    const int refused = fuzz(good, [](const std::string& b) { iwr::decode_checkpoint(b, "fuzz.ckpt: "); },
                             "checkpoint", 2);
    CHECK(refused > 0);
}

IWR_TEST(memory_estimate_refuses_huge_populations) {
    iwr::de::Settings s;
    s.lower.assign(58, -0.5);
    s.upper.assign(58, 0.5);
    s.population_size = 10'000'000;
    const iwr::de::Settings r = iwr::de::resolve(s);
    CHECK(iwr::de::memory_estimate(r) > 1e10);  // tens of GB: what the issue saw killed
    bool named = false;
    try {
        iwr::de::require_memory(r, 8'000'000'000ULL);
    } catch (const std::invalid_argument& e) {
        named = contains(e.what(), "population_size: 10000000 individuals of 58 parameters need about") &&
                contains(e.what(), "8.0 GB are available");
    }
    CHECK(named);
    s.population_size = 600;
    iwr::de::require_memory(iwr::de::resolve(s), 8'000'000'000ULL);  // the paper's: a few MB
}

}  // namespace

}  // namespace test_binary_io
