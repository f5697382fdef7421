/* cmd_mesh.c - squish mesh (not yet built). */
#include <stdio.h>

#include "app/commands.h"

int sq_cmd_mesh(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish mesh: not available in this build yet\n");
    return 2;
}
