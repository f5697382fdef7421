/* cmd_run.c - squish run (not yet built). */
#include <stdio.h>

#include "app/commands.h"

int sq_cmd_run(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish run: not available in this build yet\n");
    return 2;
}
