// The effects' tables as Python writes them (Effect.to_dict()), and the refusal helpers, shared by
// the C++ tests of the objectives with effects (test_effects.cpp, test_effects_ballbar.cpp).
#pragma once

#include <functional>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "iwr/binary_io.hpp"
#include "iwr/effects.hpp"
#include "iwr/problem_file.hpp"

namespace iwr_test {

inline iwr::EffectValue num(double v) { return {iwr::EffectValue::Type::Number, {v}}; }
inline iwr::EffectValue flag(bool v) { return {iwr::EffectValue::Type::Bool, {v ? 1.0 : 0.0}}; }
inline iwr::EffectValue nums(std::vector<double> v) { return {iwr::EffectValue::Type::Numbers, std::move(v)}; }

// Python's LegCompliance(...).to_dict() and LegThermal(...).to_dict().
inline iwr::EffectTable compliance_table(bool per_leg, double c, iwr::Vec3 gravity) {
    return {"compliance",
            {{"per_leg", flag(per_leg)},
             {"compliance_um_per_N", per_leg ? nums(std::vector<double>(6, c)) : num(c)},
             {"max_um_per_N", num(0.05)},
             {"gravity_m_s2", nums({gravity(0), gravity(1), gravity(2)})},
             {"platform_mass_kg", num(120)},
             {"platform_centre_mm", nums({5, -3, 40})}}};
}
inline iwr::EffectTable thermal_table(bool identify, bool per_leg, double alpha) {
    return {"thermal",
            {{"alpha_ppm_per_K", num(alpha)},
             {"reference_C", num(20)},
             {"identify", flag(identify)},
             {"per_leg", flag(per_leg)},
             {"max_ppm_per_K", num(30)}}};
}

// The message of the std::invalid_argument or io::FormatError that f throws ("" when none).
inline std::string refusal(const std::function<void()>& f) {
    try {
        f();
    } catch (const std::invalid_argument& e) {
        return e.what();
    } catch (const iwr::io::FormatError& e) {
        return e.what();
    }
    return "";
}
inline bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// A short fuzz of a problem file's second half (where the effects' bytes are): `trials` copies,
// each with one byte changed and resealed; how many the reader refuses with a FormatError (the
// others read; any other exception, or a crash, fails the test).
inline int fuzz_refusals(const std::string& bytes, int trials, std::mt19937_64& rng) {
    int refused = 0;
    for (int t = 0; t < trials; ++t) {
        std::string payload = bytes.substr(32);
        const std::size_t at = payload.size() / 2 + rng() % (payload.size() / 2);
        payload[at] = static_cast<char>(rng());
        iwr::io::Writer w;
        w.raw(bytes.substr(0, 16));
        w.u64(payload.size());
        w.u64(iwr::io::hash64(payload.data(), payload.size()));
        w.raw(payload);
        try {
            (void)iwr::decode_problem(w.data(), "fuzz: ");
        } catch (const iwr::io::FormatError&) {
            ++refused;
        }
    }
    return refused;
}

}  // namespace iwr_test
