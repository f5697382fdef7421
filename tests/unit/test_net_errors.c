/* test_net_errors.c - the table of protocol error codes (server/net/errors.c) against the
 * "Error codes" table of docs/protocol.md, in both directions: every code of the server is
 * documented with the same meaning, every documented code is one of the server's. A code
 * added (or reworded) on one side only fails here. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "net/errors.h"
#include "sq_test.h"
#include "util/util.h"

#define MAX_ROWS 64

typedef struct doc_row {
    char code[64];
    char meaning[512];
} doc_row;

/* the rows "| `code` | meaning |" of the section "### Error codes"; -1 if it is missing */
static int read_doc_table(doc_row *rows, int max)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/../../docs/protocol.md", sq_test_data());
    sq_err err = {{0}};
    char *text = sq_read_file(path, NULL, 1u << 22, &err);
    if (!text) {
        fprintf(stderr, "  %s\n", err.msg);
        return -1;
    }
    const char *sec = strstr(text, "\n### Error codes\n");
    if (!sec) {
        free(text);
        return -1;
    }
    sec += 1;
    const char *end = strstr(sec + 4, "\n#");
    int n = 0;
    for (const char *line = sec; line && (!end || line < end); line = strchr(line, '\n')) {
        if (*line == '\n')
            line++;
        const char *eol = strchr(line, '\n');
        size_t len = eol ? (size_t)(eol - line) : strlen(line);
        if (len > 6 && !strncmp(line, "| `", 3)) {
            const char *c1 = line + 3, *c2 = memchr(c1, '`', len - 3);
            if (c2 && n < max && (size_t)(c2 - c1) < sizeof rows[n].code && !strncmp(c2, "` | ", 4)) {
                snprintf(rows[n].code, sizeof rows[n].code, "%.*s", (int)(c2 - c1), c1);
                const char *m = c2 + 4, *me = line + len;
                if (me - m >= 2 && !strncmp(me - 2, " |", 2))
                    me -= 2;
                snprintf(rows[n].meaning, sizeof rows[n].meaning, "%.*s", (int)(me - m), m);
                n++;
            }
        }
        if (!eol)
            break;
        line = eol;
    }
    free(text);
    return n;
}

SQ_TEST(net_errors_documented)
{
    doc_row rows[MAX_ROWS];
    int n = read_doc_table(rows, MAX_ROWS);
    CHECK(n > 0);
    /* every code of the server: in the document, once, with its meaning */
    for (int c = 0; c < SQ_CODE_COUNT; c++) {
        const char *name = sq_net_code_name((sq_net_code)c);
        CHECK(name[0] != 0);
        CHECK(sq_net_code_meaning((sq_net_code)c)[0] != 0);
        int found = 0;
        for (int i = 0; i < n; i++)
            if (!strcmp(rows[i].code, name)) {
                found++;
                if (strcmp(rows[i].meaning, sq_net_code_meaning((sq_net_code)c))) {
                    fprintf(stderr, "  code %s: docs/protocol.md says \"%s\", server/net/errors.c "
                            "\"%s\"\n", name, rows[i].meaning, sq_net_code_meaning((sq_net_code)c));
                    CHECK(!"meanings differ");
                }
            }
        if (found != 1)
            fprintf(stderr, "  code %s: %d rows in the Error codes table of docs/protocol.md\n",
                    name, found);
        CHECK(found == 1);
        CHECK(sq_net_code_of(name) == (sq_net_code)c);
    }
    /* every documented code: one of the server's */
    for (int i = 0; i < n; i++) {
        int found = 0;
        for (int c = 0; c < SQ_CODE_COUNT; c++)
            found |= !strcmp(rows[i].code, sq_net_code_name((sq_net_code)c));
        if (!found)
            fprintf(stderr, "  code %s: documented in docs/protocol.md, not in server/net/errors.c\n",
                    rows[i].code);
        CHECK(found);
    }
    CHECK(n == SQ_CODE_COUNT);
    /* out of the table: empty names, and a name not in it maps to internal */
    CHECK(sq_net_code_name(SQ_CODE_COUNT)[0] == 0);
    CHECK(sq_net_code_of("no_such_code") == SQ_CODE_INTERNAL);
}
