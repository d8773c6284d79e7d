// Robots shared by the C++ tests.
#pragma once

#include <cmath>

#include "iwr/model.hpp"

namespace iwr_test {

// The default IWR of docs/model.md (legs pairing 40 degrees apart: not architecturally singular);
// without the carriage, the hexapod alone.
inline iwr::Geometry default_iwr(bool with_carriage = true) {
    const double h = M_PI / 2;
    iwr::RowMatrixXd dh(4, 4);
    dh << h, 0, 500, 0, h, 0, 300, h, h, 400, 250, 0, -h, 300, 0, 0;
    iwr::LegMatrix base, platform;
    const double b_deg[6] = {-10, 10, 110, 130, 230, 250}, p_deg[6] = {-50, 50, 70, 170, 190, 290};
    for (int j = 0; j < 6; ++j) {
        base.row(j) << 400 * std::cos(b_deg[j] * M_PI / 180), 400 * std::sin(b_deg[j] * M_PI / 180),
            0;
        platform.row(j) << 250 * std::cos(p_deg[j] * M_PI / 180),
            250 * std::sin(p_deg[j] * M_PI / 180), 0;
    }
    const iwr::LegVector l0 = iwr::LegVector::Constant(600);
    if (!with_carriage) return iwr::Geometry("", iwr::RowMatrixXd(0, 4), base, platform, l0);
    return iwr::Geometry("PPRR", dh, base, platform, l0);
}

}  // namespace iwr_test
