/* main.c - unit test runner: ./unit_tests [NAME_SUBSTRING ...] */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "sq_test.h"

#define MAX_TESTS 1024

static struct {
    const char *name;
    sq_test_fn fn;
} tests[MAX_TESTS];
static int ntests;
static int current_failures;
static char tmpdir[256];

void sq_test_register(const char *name, sq_test_fn fn)
{
    if (ntests < MAX_TESTS) {
        tests[ntests].name = name;
        tests[ntests].fn = fn;
        ntests++;
    }
}

void sq_test_fail(const char *file, int line, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stdout, "    %s:%d: ", file, line);
    vfprintf(stdout, fmt, ap);
    fputc('\n', stdout);
    va_end(ap);
    current_failures++;
}

const char *sq_test_data(void)
{
    const char *d = getenv("SQ_TEST_DATA");
    return d ? d : "tests/data";
}

const char *sq_test_tmpdir(void)
{
    if (!tmpdir[0]) {
        snprintf(tmpdir, sizeof tmpdir, "/tmp/squish-unit-XXXXXX");
        if (!mkdtemp(tmpdir)) {
            perror("mkdtemp");
            exit(2);
        }
    }
    return tmpdir;
}

static int cmp_tests(const void *a, const void *b)
{
    return strcmp(*(const char *const *)a, *(const char *const *)b);
}

int main(int argc, char **argv)
{
    qsort(tests, ntests, sizeof tests[0], cmp_tests);
    int passed = 0, failed = 0;
    for (int i = 0; i < ntests; i++) {
        int selected = argc < 2;
        for (int a = 1; a < argc; a++)
            if (strstr(tests[i].name, argv[a]))
                selected = 1;
        if (!selected)
            continue;
        current_failures = 0;
        printf("  run  %s\n", tests[i].name);
        fflush(stdout);
        tests[i].fn();
        if (current_failures) {
            printf("  FAIL %s (%d checks failed)\n", tests[i].name, current_failures);
            failed++;
        } else {
            printf("  ok   %s\n", tests[i].name);
            passed++;
        }
        fflush(stdout);
    }
    printf("unit: %d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
