/* cmd_bench.c - squish bench (not yet built). */
#include <stdio.h>

#include "app/commands.h"

int sq_cmd_bench(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish bench: not available in this build yet\n");
    return 2;
}
