/* cmd_tradeoff.c - squish tradeoff and squish sweep (not yet built). */
#include <errno.h>
#include <stdio.h>
#include <sys/stat.h>

#include "app/commands.h"
#include "app/tradeoff.h"

int sq_cmd_tradeoff(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish tradeoff: not available in this build yet\n");
    return 2;
}

int sq_tradeoff_mkdir(const char *dir)
{
    char buf[1024];
    snprintf(buf, sizeof buf, "%s", dir);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/')
            continue;
        *p = 0;
        if (mkdir(buf, 0777) && errno != EEXIST)
            return -1;
        *p = '/';
    }
    if (mkdir(buf, 0777) && errno != EEXIST)
        return -1;
    struct stat st;
    if (stat(buf, &st) != 0)
        return -1;
    if (!S_ISDIR(st.st_mode)) {
        errno = ENOTDIR;
        return -1;
    }
    return 0;
}
