// The C++ tests' one assertion macro: CHECK(cond) reports a failed condition with its file and
// line and counts it, without stopping the test; finish() turns the count into the exit code.
#pragma once

#include <cstdio>

namespace iwr_test {

inline int failures = 0;

// Exit code of a test executable: 0 and `passed` when every CHECK held, else 1 and the count.
inline int finish(const char* passed) {
    if (failures) {
        std::fprintf(stderr, "%d check(s) failed\n", failures);
        return 1;
    }
    std::printf("%s\n", passed);
    return 0;
}

}  // namespace iwr_test

#define CHECK(cond)                                                                    \
    do {                                                                               \
        if (!(cond)) {                                                                 \
            std::fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
            ++iwr_test::failures;                                                      \
        }                                                                              \
    } while (0)
