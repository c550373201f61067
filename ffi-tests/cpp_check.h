// The C++ test programs' checks and runner (C++11): CHECK returns false
// from a test with the failed condition on stderr; run_tests runs each,
// counts an escaping exception as a failure, and prints the
// "N passed, M failed" line tests/c_abi.rs reads.
#ifndef SHEAF_CPP_CHECK_H
#define SHEAF_CPP_CHECK_H

#include <cstddef>
#include <cstdio>
#include <exception>

#define CHECK(cond)                                                                           \
    do {                                                                                      \
        if (!(cond)) {                                                                        \
            std::fprintf(stderr, "    %s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
            return false;                                                                     \
        }                                                                                     \
    } while (0)

struct NamedTest {
    const char *name;
    bool (*run)();
};

template <std::size_t N> inline int run_tests(const NamedTest (&tests)[N]) {
    int passed = 0, failed = 0;
    for (std::size_t i = 0; i < N; ++i) {
        bool ok = false;
        try {
            ok = tests[i].run();
        } catch (const std::exception &e) {
            std::fprintf(stderr, "    unexpected exception: %s\n", e.what());
        }
        std::printf("%s: %s\n", ok ? "PASSED" : "FAILED", tests[i].name);
        (ok ? passed : failed) += 1;
    }
    std::printf("%d passed, %d failed\n", passed, failed);
    return failed == 0 ? 0 : 1;
}

#endif
