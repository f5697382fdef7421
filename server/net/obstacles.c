/* obstacles.c - the scene's obstacles in the protocol (docs/protocol.md): their shapes in
 * opened/joined, the moving ones' offsets with every frame and in stats. */
#include "net/server.h"

#include <cjson/cJSON.h>
#include <string.h>

static const char *const kind_names[] = {"plane", "box", "sphere", "capsule", "mesh"};

int sq_net_obstacles_move(const sq_scene *sc)
{
    for (int o = 0; sc && o < sc->nobstacles; o++)
        if (sc->obstacles[o].nkeys > 0)
            return 1;
    return 0;
}

cJSON *sq_obstacles_json(const sq_scene *sc)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; sc && i < sc->nobstacles; i++) {
        const sq_obstacle *ob = &sc->obstacles[i].obstacle;
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "name", ob->name);
        cJSON_AddStringToObject(o, "type", kind_names[(unsigned)ob->kind % 5]);
        switch (ob->kind) {
        case SQ_OBSTACLE_PLANE:
            cJSON_AddItemToObject(o, "point", cJSON_CreateDoubleArray(ob->point, 3));
            cJSON_AddItemToObject(o, "normal", cJSON_CreateDoubleArray(ob->normal, 3));
            break;
        case SQ_OBSTACLE_BOX: {
            double size[3] = {2 * ob->half[0], 2 * ob->half[1], 2 * ob->half[2]};
            cJSON_AddItemToObject(o, "center", cJSON_CreateDoubleArray(ob->point, 3));
            cJSON_AddItemToObject(o, "size", cJSON_CreateDoubleArray(size, 3));
            break;
        }
        case SQ_OBSTACLE_SPHERE:
            cJSON_AddItemToObject(o, "center", cJSON_CreateDoubleArray(ob->point, 3));
            cJSON_AddNumberToObject(o, "radius", ob->radius);
            break;
        case SQ_OBSTACLE_CAPSULE:
            cJSON_AddItemToObject(o, "a", cJSON_CreateDoubleArray(ob->point, 3));
            cJSON_AddItemToObject(o, "b", cJSON_CreateDoubleArray(ob->end, 3));
            cJSON_AddNumberToObject(o, "radius", ob->radius);
            break;
        case SQ_OBSTACLE_MESH: {
            const sq_trimesh *m = ob->mesh;
            cJSON_AddItemToObject(o, "vertices", cJSON_CreateDoubleArray(m->x, 3 * m->nverts));
            cJSON_AddItemToObject(o, "triangles", cJSON_CreateIntArray(m->tris, 3 * m->ntris));
            cJSON_AddNumberToObject(o, "thickness", ob->thickness);
            break;
        }
        }
        cJSON *f = cJSON_AddObjectToObject(o, "friction");
        cJSON_AddNumberToObject(f, "static", ob->mu_s);
        cJSON_AddNumberToObject(f, "kinetic", ob->mu_k);
        cJSON_AddBoolToObject(o, "moving", sc->obstacles[i].nkeys > 0);
        cJSON_AddItemToArray(a, o);
    }
    return a;
}

cJSON *sq_obstacle_offsets_json(const sq_scene *sc, const double (*pos)[3], int n)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; sc && i < n && i < sc->nobstacles; i++) {
        const double *p0 = sc->obstacles[i].obstacle.point;
        double off[3] = {pos[i][0] - p0[0], pos[i][1] - p0[1], pos[i][2] - p0[2]};
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "name", sc->obstacles[i].obstacle.name);
        cJSON_AddItemToObject(o, "offset", cJSON_CreateDoubleArray(off, 3));
        cJSON_AddItemToArray(a, o);
    }
    return a;
}

cJSON *sq_obstacles_frame_json(const sq_world *w)
{
    cJSON *o = sq_reply_new("obstacles", NULL);
    cJSON_AddNumberToObject(o, "frame", (double)w->frame);
    double pos[SQ_MAX_OBSTACLES][3];
    for (int i = 0; i < w->nobstacles; i++)
        memcpy(pos[i], w->obstacles[i].point, sizeof pos[i]);
    cJSON_AddItemToObject(o, "obstacles", sq_obstacle_offsets_json(w->scene, (const double (*)[3])pos, w->nobstacles));
    return o;
}
