/* sq_test.h - a tiny unit-test harness: tests register themselves, one runner executes
 * them (optionally filtered by a name substring) and prints "N passed, N failed". */
#ifndef SQ_TEST_H
#define SQ_TEST_H

#include <math.h>
#include <stdio.h>

typedef void (*sq_test_fn)(void);
void sq_test_register(const char *name, sq_test_fn fn);
void sq_test_fail(const char *file, int line, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

/* define a test: SQ_TEST(mesh_box_counts) { CHECK(...); } */
#define SQ_TEST(name)                                                                   \
    static void name(void);                                                             \
    __attribute__((constructor)) static void sq_register_##name(void)                   \
    {                                                                                   \
        sq_test_register(#name, name);                                                  \
    }                                                                                   \
    static void name(void)

#define CHECK(cond)                                                                     \
    do {                                                                                \
        if (!(cond))                                                                    \
            sq_test_fail(__FILE__, __LINE__, "CHECK(%s)", #cond);                       \
    } while (0)

/* |a - b| <= tol, with both values printed on failure */
#define CHECK_NEAR(a, b, tol)                                                           \
    do {                                                                                \
        double sq_a_ = (a), sq_b_ = (b), sq_t_ = (tol);                                 \
        if (!(fabs(sq_a_ - sq_b_) <= sq_t_))                                            \
            sq_test_fail(__FILE__, __LINE__, "CHECK_NEAR(%s, %s, %s): %.9g vs %.9g (diff %.3g > %.3g)", \
                         #a, #b, #tol, sq_a_, sq_b_, fabs(sq_a_ - sq_b_), sq_t_);       \
    } while (0)

/* a message containing a substring */
#define CHECK_CONTAINS(haystack, needle)                                                \
    do {                                                                                \
        const char *sq_h_ = (haystack), *sq_n_ = (needle);                              \
        if (!sq_h_ || !strstr(sq_h_, sq_n_))                                            \
            sq_test_fail(__FILE__, __LINE__, "'%s' does not contain '%s'",              \
                         sq_h_ ? sq_h_ : "(null)", sq_n_);                              \
    } while (0)

/* directory of test data (tests/data), set by the runner from SQ_TEST_DATA or default */
const char *sq_test_data(void);
/* a fresh temporary directory for this test run */
const char *sq_test_tmpdir(void);

#endif
