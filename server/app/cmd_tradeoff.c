/* cmd_tradeoff.c - squish tradeoff and squish sweep (not yet built). */
#include <stdio.h>

#include "app/commands.h"

int sq_cmd_tradeoff(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish tradeoff: not available in this build yet\n");
    return 2;
}

int sq_cmd_sweep(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish sweep: not available in this build yet\n");
    return 2;
}
