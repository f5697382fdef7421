/* cmd_serve.c - squish serve (not yet built). */
#include <stdio.h>

#include "app/commands.h"

int sq_cmd_serve(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish serve: not available in this build yet\n");
    return 2;
}
