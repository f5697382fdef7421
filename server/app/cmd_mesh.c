/* cmd_mesh.c - `squish mesh info | box | convert`: inspect, generate and convert meshes. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/commands.h"
#include "mesh/mesh.h"

static void usage(FILE *f)
{
    fprintf(f,
            "usage:\n"
            "  squish mesh info FILE\n"
            "      counts, volume, surface area, edge lengths, dihedral angles, worst aspect ratio,\n"
            "      smallest tet height\n"
            "  squish mesh box NX NY NZ [--size X Y Z] [--origin X Y Z] [--renumber] --out FILE\n"
            "      structured box of NX*NY*NZ cells, 6 tets each (default size 1 1 1, origin 0 0 0);\n"
            "      nodes numbered lexicographically (x fastest)\n"
            "  squish mesh convert IN OUT [--renumber]\n"
            "      read any supported format, validate, write another\n"
            "  --renumber: number the nodes by reverse Cuthill-McKee (neighbours close together, tets\n"
            "      sorted by their first node) before writing: faster steps on meshes whose numbering\n"
            "      is not local (Gmsh's); prints the bandwidth before and after\n"
            "\n"
            "formats (by extension): .msh (Gmsh 2.2 or 4.1 ASCII; written as 2.2), .node/.ele (TetGen),\n"
            ".mesh (Medit), .vtk (legacy VTK, write only).\n"
            "exit status: 0 ok, 1 bad or unreadable file, 2 usage error\n");
}

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "squish mesh: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\nrun 'squish mesh --help' for usage\n");
    return 2;
}

static int wants_help(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h"))
            return 1;
    return 0;
}

/* parse a whole string as an int / a finite double */
static int parse_int(const char *s, int *v)
{
    char *end;
    errno = 0;
    long x = strtol(s, &end, 10);
    if (!*s || *end || errno || x < -2147483647L || x > 2147483647L)
        return -1;
    *v = (int)x;
    return 0;
}

static int parse_double(const char *s, double *v)
{
    char *end;
    double x = strtod(s, &end);
    if (!*s || *end || !isfinite(x))
        return -1;
    *v = x;
    return 0;
}

static int cmd_info(int argc, char **argv)
{
    if (argc != 2)
        return usage_error("info takes exactly one FILE%s", "");
    sq_err err = {0};
    double t0 = sq_now();
    sq_mesh *m = sq_mesh_load(argv[1], &err);
    if (!m) {
        fprintf(stderr, "squish mesh info: %s\n", err.msg);
        return 1;
    }
    double t1 = sq_now();
    sq_mesh_info in;
    sq_mesh_measure(m, &in);
    printf("file:            %s\n", argv[1]);
    printf("nodes:           %d\n", in.nnodes);
    printf("tets:            %d\n", in.ntets);
    printf("edges:           %d\n", in.nedges);
    printf("boundary tris:   %d\n", in.ntris);
    printf("boundary nodes:  %d\n", in.nsurf);
    printf("bbox:            [%g %g %g] .. [%g %g %g]\n", m->bbox_min[0], m->bbox_min[1], m->bbox_min[2],
           m->bbox_max[0], m->bbox_max[1], m->bbox_max[2]);
    printf("volume:          %.9g\n", in.volume);
    printf("surface area:    %.9g\n", in.surface_area);
    printf("edge length:     min %.6g  mean %.6g  max %.6g\n", in.edge_min, in.edge_mean, in.edge_max);
    printf("dihedral angle:  min %.3f  max %.3f deg\n", in.dihedral_min_deg, in.dihedral_max_deg);
    printf("aspect ratio:    max %.4g (longest edge / smallest height of a tet)\n", in.aspect_max);
    printf("smallest height: %.6g\n", in.height_min);
    printf("load time:       %.3f s\n", t1 - t0);
    sq_mesh_free(m);
    return 0;
}

/* --renumber: replace *m by its RCM renumbering, printing the bandwidths; -1 on failure */
static int renumber(sq_mesh **m, const char *who)
{
    sq_err err = {0};
    double t0 = sq_now();
    int before = sq_mesh_bandwidth(*m);
    sq_mesh *r = sq_mesh_renumber(*m, &err);
    if (!r) {
        fprintf(stderr, "squish mesh %s: %s\n", who, err.msg);
        return -1;
    }
    printf("renumbered (reverse Cuthill-McKee): bandwidth %d -> %d (%.3f s)\n", before, sq_mesh_bandwidth(r),
           sq_now() - t0);
    sq_mesh_free(*m);
    *m = r;
    return 0;
}

static int cmd_box(int argc, char **argv)
{
    int n[3], npos = 0;
    double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
    const char *out = NULL;
    int renum = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--renumber")) {
            renum = 1;
        } else if (!strcmp(a, "--size") || !strcmp(a, "--origin")) {
            double *dst = !strcmp(a, "--size") ? size : origin;
            if (i + 3 >= argc)
                return usage_error("%s needs three numbers X Y Z", a);
            for (int c = 0; c < 3; c++)
                if (parse_double(argv[i + 1 + c], &dst[c]) < 0)
                    return usage_error("not a finite number: '%s'", argv[i + 1 + c]);
            i += 3;
        } else if (!strcmp(a, "--out") || !strcmp(a, "-o")) {
            if (i + 1 >= argc)
                return usage_error("%s needs a FILE", a);
            out = argv[++i];
        } else if (a[0] == '-' && a[1] && !(a[1] >= '0' && a[1] <= '9')) {
            return usage_error("unknown option '%s'", a);
        } else {
            if (npos == 3)
                return usage_error("box takes three cell counts NX NY NZ; extra argument '%s'", a);
            if (parse_int(a, &n[npos]) < 0 || n[npos] < 1)
                return usage_error("cell count must be a positive integer, got '%s'", a);
            npos++;
        }
    }
    if (npos != 3)
        return usage_error("box needs three cell counts NX NY NZ%s", "");
    if (!out)
        return usage_error("box needs --out FILE (.msh, .mesh, .node, .vtk)%s", "");
    for (int c = 0; c < 3; c++)
        if (!(size[c] > 0))
            return usage_error("--size values must be positive%s", "");
    sq_err err = {0};
    double t0 = sq_now();
    sq_mesh *m = sq_mesh_box(n[0], n[1], n[2], size, origin, &err);
    if (!m) {
        fprintf(stderr, "squish mesh box: %s\n", err.msg);
        return 2;
    }
    if (renum && renumber(&m, "box") < 0) {
        sq_mesh_free(m);
        return 1;
    }
    double t1 = sq_now();
    if (sq_mesh_save(m, out, &err) < 0) {
        fprintf(stderr, "squish mesh box: %s\n", err.msg);
        sq_mesh_free(m);
        return 1;
    }
    printf("wrote %s: %d nodes, %d tets, %d boundary triangles (built in %.3f s, written in %.3f s)\n", out,
           m->nnodes, m->ntets, m->ntris, t1 - t0, sq_now() - t1);
    sq_mesh_free(m);
    return 0;
}

static int cmd_convert(int argc, char **argv)
{
    const char *io[2] = {NULL, NULL};
    int nio = 0, renum = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--renumber"))
            renum = 1;
        else if (argv[i][0] == '-' && argv[i][1])
            return usage_error("unknown option '%s'", argv[i]);
        else if (nio == 2)
            return usage_error("convert takes IN and OUT%s", "");
        else
            io[nio++] = argv[i];
    }
    if (nio != 2)
        return usage_error("convert takes IN and OUT%s", "");
    sq_err err = {0};
    sq_mesh *m = sq_mesh_load(io[0], &err);
    if (!m) {
        fprintf(stderr, "squish mesh convert: %s\n", err.msg);
        return 1;
    }
    if (renum && renumber(&m, "convert") < 0) {
        sq_mesh_free(m);
        return 1;
    }
    if (sq_mesh_save(m, io[1], &err) < 0) {
        fprintf(stderr, "squish mesh convert: %s\n", err.msg);
        sq_mesh_free(m);
        /* an unknown output extension is a usage error */
        return strstr(err.msg, "unknown output format") ? 2 : 1;
    }
    printf("wrote %s: %d nodes, %d tets\n", io[1], m->nnodes, m->ntets);
    sq_mesh_free(m);
    return 0;
}

int sq_cmd_mesh(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    const char *sub = argv[1];
    if (!strcmp(sub, "--help") || !strcmp(sub, "-h") || !strcmp(sub, "help")) {
        usage(stdout);
        return 0;
    }
    if (wants_help(argc - 1, argv + 1)) {
        usage(stdout);
        return 0;
    }
    if (!strcmp(sub, "info"))
        return cmd_info(argc - 1, argv + 1);
    if (!strcmp(sub, "box"))
        return cmd_box(argc - 1, argv + 1);
    if (!strcmp(sub, "convert"))
        return cmd_convert(argc - 1, argv + 1);
    return usage_error("unknown subcommand '%s' (info, box, convert)", sub);
}
