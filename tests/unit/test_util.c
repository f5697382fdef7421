/* test_util.c - error formatting, hashing, file reading. */
#include <string.h>

#include "sq_test.h"
#include "util/util.h"

SQ_TEST(util_err_prefix_keeps_message)
{
    sq_err e = {{0}};
    CHECK(sq_err_set(&e, "line %d: bad index %d", 12, -3) == -1);
    sq_err_prefix(&e, "cube.msh");
    CHECK(strcmp(e.msg, "cube.msh: line 12: bad index -3") == 0);
}

SQ_TEST(util_hash_differs_on_one_byte)
{
    unsigned char a[8] = {1, 2, 3, 4, 5, 6, 7, 8}, b[8] = {1, 2, 3, 4, 5, 6, 7, 9};
    CHECK(sq_hash_bytes(SQ_HASH_INIT, a, 8) != sq_hash_bytes(SQ_HASH_INIT, b, 8));
    CHECK(sq_hash_bytes(SQ_HASH_INIT, a, 8) == sq_hash_bytes(SQ_HASH_INIT, a, 8));
}

SQ_TEST(util_read_file_missing_names_path)
{
    sq_err e = {{0}};
    CHECK(sq_read_file("/nonexistent/squish.json", NULL, 1 << 20, &e) == NULL);
    CHECK_CONTAINS(e.msg, "/nonexistent/squish.json");
}
