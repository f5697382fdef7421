/* cmd_render.c - squish render (not yet built). */
#include <stdio.h>

#include "app/commands.h"

int sq_cmd_render(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish render: not available in this build yet\n");
    return 2;
}
