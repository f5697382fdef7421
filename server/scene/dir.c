/* dir.c - the scene directory: the scenes a server offers, loaded from --scenes DIR.
 *
 * Every *.json of the directory, in name order, loaded and validated (sq_scene_load) and
 * checked against the engine (sq_scene_check); a bad file is reported and skipped, and so is
 * a second file with a name already taken (clients open scenes by their "name"). The server
 * (server/net) asks this list for the names and the scenes; it never reads scene files.
 */
#include "scene/scene.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int has_suffix(const char *s, const char *suf)
{
    size_t a = strlen(s), b = strlen(suf);
    return a >= b && !strcmp(s + a - b, suf);
}

static int cmp_str(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

void sq_scene_list_add(sq_scene_list *l, sq_scene *sc, const char *name)
{
    l->scenes = sq_realloc(l->scenes, sizeof *l->scenes * (size_t)(l->n + 1));
    l->names = sq_realloc(l->names, sizeof *l->names * (size_t)(l->n + 1));
    l->scenes[l->n] = sc;
    snprintf(l->names[l->n], sizeof l->names[l->n], "%s", name);
    l->n++;
}

int sq_scene_list_find(const sq_scene_list *l, const char *name)
{
    int sc = -1;
    for (int i = 0; i < l->n; i++)
        if (!strcmp(l->names[i], name))
            sc = i;
    return sc;
}

void sq_scene_list_free(sq_scene_list *l)
{
    for (int i = 0; i < l->n; i++)
        sq_scene_free(l->scenes[i]);
    free(l->scenes);
    free(l->names);
    memset(l, 0, sizeof *l);
}

int sq_scene_list_load_dir(sq_scene_list *l, const char *dir, const char *who)
{
    DIR *d = opendir(dir);
    if (!d)
        return -1;
    char **files = NULL;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)))
        if (e->d_name[0] != '.' && has_suffix(e->d_name, ".json")) {
            files = sq_realloc(files, sizeof *files * (size_t)(n + 1));
            files[n++] = sq_strdup(e->d_name);
        }
    closedir(d);
    if (n)
        qsort(files, (size_t)n, sizeof *files, cmp_str);
    for (int i = 0; i < n; i++) {
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", dir, files[i]);
        sq_err err = {{0}};
        sq_scene *sc = sq_scene_load(path, &err);
        /* what only the engine can tell (every node fixed, a step bound needing more than
         * 2^20 substeps, ...): a scene that cannot start is not offered */
        if (sc && sq_scene_check(sc, &err)) {
            sq_scene_free(sc);
            sc = NULL;
        }
        int dup = sc ? sq_scene_list_find(l, sc->name) : -1;
        if (!sc) {
            fprintf(stderr, "%s: skipping scene %s\n", who, err.msg);
        } else if (dup >= 0) {
            /* clients open scenes by their "name": two files may not share one */
            fprintf(stderr, "%s: skipping scene %s: its name \"%s\" is already the name "
                    "of %s; give each scene file its own \"name\"\n", who, path, sc->name,
                    l->scenes[dup]->path);
            sq_scene_free(sc);
        } else {
            /* the scene's "name" (sq_scene_load gives the file's base name without one) */
            sq_scene_list_add(l, sc, sc->name);
        }
        free(files[i]);
    }
    free(files);
    return 0;
}
