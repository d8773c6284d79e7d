// The C++ tests' harness. CHECK(cond) reports a failed condition with its file and line and counts
// it, without stopping the case. IWR_TEST(name) defines a case; the test program (iwr_cpp_tests,
// every test_*.cpp but test_de_isa.cpp) run with a case's name runs that case alone (CMake
// registers one ctest test per case, from the IWR_TEST lines of the sources), with --list prints
// the names, and with no argument runs every case. The files are compiled as one translation unit
// (CMakeLists.txt): each file's code is in a namespace of its own (test_de, ...), a case's name is
// unique across the files, and IWR_TEST_MAIN is in test_main.cpp alone.
#pragma once

#include <cstdio>
#include <cstring>
#include <exception>
#include <string>
#include <vector>

namespace iwr_test {

inline int failures = 0;

struct Case {
    const char* name;
    void (*fn)();
};

inline std::vector<Case>& cases() {
    static std::vector<Case> all;
    return all;
}

struct Register {
    Register(const char* name, void (*fn)()) { cases().push_back({name, fn}); }
};

inline int run_case(const Case& c) {
    const int before = failures;
    try {
        c.fn();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "%s: unexpected exception: %s\n", c.name, e.what());
        ++failures;
    }
    std::printf("%s: %s\n", c.name, failures == before ? "passed" : "FAILED");
    return failures == before ? 0 : 1;
}

inline int main(int argc, char** argv) {
    if (argc > 1 && std::strcmp(argv[1], "--list") == 0) {
        for (const Case& c : cases()) std::printf("%s\n", c.name);
        return 0;
    }
    int failed = 0;
    bool found = argc < 2;
    for (const Case& c : cases()) {
        if (argc > 1 && std::strcmp(argv[1], c.name) != 0) continue;
        found = true;
        failed += run_case(c);
    }
    if (!found) {
        std::fprintf(stderr, "no test case '%s' (--list shows them)\n", argv[1]);
        return 2;
    }
    if (failures) std::fprintf(stderr, "%d check(s) failed in %d case(s)\n", failures, failed);
    return failures ? 1 : 0;
}

}  // namespace iwr_test

#define CHECK(cond)                                                                    \
    do {                                                                               \
        if (!(cond)) {                                                                 \
            std::fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
            ++iwr_test::failures;                                                      \
        }                                                                              \
    } while (0)

// At the start of a line, so that CMake finds the case's name there.
#define IWR_TEST(name)                                                     \
    void name();                                                           \
    static const iwr_test::Register name##_registered(#name, &name);     \
    void name()

#define IWR_TEST_MAIN \
    int main(int argc, char** argv) { return iwr_test::main(argc, argv); }
