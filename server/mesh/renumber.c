/* renumber.c - node renumbering for memory locality: reverse Cuthill-McKee.
 *
 * The step kernel walks each node's row of the stiffness (its neighbours' blocks and
 * displacements): with neighbours numbered close together those reads stay in cache. Gmsh's
 * numbering is not local (its HXT mesher numbers by insertion), structured boxes are
 * (lexicographic). RCM numbers breadth-first from a pseudo-peripheral node, neighbours by
 * increasing degree, then reverses; the tets are then sorted by their smallest new node index.
 * Deterministic: every tie goes to the lower old index.
 */
#include "mesh/mesh.h"

#include <stdlib.h>
#include <string.h>

int sq_mesh_bandwidth(const sq_mesh *m)
{
    int bw = 0;
    for (int i = 0; i < m->nnodes; i++)
        for (int p = m->adj_start[i]; p < m->adj_start[i + 1]; p++) {
            int d = abs(m->adj[p] - i);
            if (d > bw)
                bw = d;
        }
    return bw;
}

static int degree(const sq_mesh *m, int i)
{
    return m->adj_start[i + 1] - m->adj_start[i];
}

/* breadth-first levels from s over the unvisited nodes (seen[] == 0): order[] gets them in BFS
 * order, neighbours by increasing degree (ties: lower index); returns the count, *last the
 * node of smallest degree in the last level; seen[] is set to mark for the visited nodes */
static int bfs(const sq_mesh *m, int s, int *seen, int mark, int *order, int *last, int *nb)
{
    int head = 0, n = 0;
    order[n++] = s;
    seen[s] = mark;
    int level_start = 0, level_end = 1;
    while (head < n) {
        int i = order[head++];
        int k = 0;
        for (int p = m->adj_start[i]; p < m->adj_start[i + 1]; p++) {
            int j = m->adj[p];
            if (seen[j] == 0)
                nb[k++] = j;
        }
        /* insertion sort by (degree, index): rows are short */
        for (int a = 1; a < k; a++) {
            int v = nb[a], dv = degree(m, v), b = a - 1;
            while (b >= 0 && (degree(m, nb[b]) > dv || (degree(m, nb[b]) == dv && nb[b] > v))) {
                nb[b + 1] = nb[b];
                b--;
            }
            nb[b + 1] = v;
        }
        for (int a = 0; a < k; a++) {
            seen[nb[a]] = mark;
            order[n++] = nb[a];
        }
        if (head == level_end) {
            if (n == level_end)
                break; /* no further level: the last one is [level_start, level_end) */
            level_start = level_end;
            level_end = n;
        }
    }
    /* the last level is order[level_start .. n) */
    int best = order[level_start];
    for (int a = level_start; a < n; a++)
        if (degree(m, order[a]) < degree(m, best) || (degree(m, order[a]) == degree(m, best) && order[a] < best))
            best = order[a];
    *last = best;
    return n;
}

typedef struct tet_key {
    int key, index;
} tet_key;

static int tet_key_cmp(const void *pa, const void *pb)
{
    const tet_key *a = pa, *b = pb;
    if (a->key != b->key)
        return (a->key > b->key) - (a->key < b->key);
    return (a->index > b->index) - (a->index < b->index);
}

sq_mesh *sq_mesh_renumber(const sq_mesh *m, sq_err *err)
{
    int n = m->nnodes;
    int maxdeg = 0;
    for (int i = 0; i < n; i++)
        if (degree(m, i) > maxdeg)
            maxdeg = degree(m, i);
    int *seen = calloc((size_t)n, sizeof *seen), *order = malloc(sizeof *order * (size_t)n);
    int *tmp = malloc(sizeof *tmp * (size_t)n), *nb = malloc(sizeof *nb * (size_t)(maxdeg + 1));
    int *newid = malloc(sizeof *newid * (size_t)n);
    double *x = malloc(sizeof *x * 3 * (size_t)n);
    int *tets = malloc(sizeof *tets * 4 * (size_t)m->ntets);
    tet_key *tk = malloc(sizeof *tk * (size_t)(m->ntets > 0 ? m->ntets : 1));
    sq_mesh *out = NULL;
    if (!seen || !order || !tmp || !nb || !newid || !x || !tets || !tk) {
        sq_err_set(err, "%s: out of memory renumbering %d nodes", m->source, n);
        goto done;
    }
    int placed = 0;
    while (placed < n) {
        /* the next component: start from its unvisited node of smallest degree (lowest index) */
        int s = -1;
        for (int i = 0; i < n; i++)
            if (!seen[i] && (s < 0 || degree(m, i) < degree(m, s)))
                s = i;
        /* pseudo-peripheral start: BFS twice more from the last level's smallest-degree node,
         * on a scratch marking (the component's nodes are marked -1 .. -3, then reset) */
        int last = s, cnt = 0;
        for (int pass = 0; pass < 3; pass++) {
            int start = last;
            cnt = bfs(m, start, seen, -1 - pass, tmp, &last, nb);
            for (int a = 0; a < cnt; a++)
                seen[tmp[a]] = 0;
            if (pass > 0 && last == start)
                break;
        }
        (void)cnt;
        int got = bfs(m, last, seen, 1, order + placed, &last, nb);
        placed += got;
    }
    /* reverse: new index of old node order[a] is n - 1 - a */
    for (int a = 0; a < n; a++)
        newid[order[a]] = n - 1 - a;
    for (int i = 0; i < n; i++)
        memcpy(x + 3 * (size_t)newid[i], m->x + 3 * (size_t)i, 3 * sizeof *x);
    for (int t = 0; t < m->ntets; t++) {
        int k = n;
        for (int c = 0; c < 4; c++) {
            int v = newid[m->tets[4 * (size_t)t + c]];
            if (v < k)
                k = v;
        }
        tk[t] = (tet_key){k, t};
    }
    qsort(tk, (size_t)m->ntets, sizeof *tk, tet_key_cmp);
    for (int t = 0; t < m->ntets; t++)
        for (int c = 0; c < 4; c++)
            tets[4 * (size_t)t + c] = newid[m->tets[4 * (size_t)tk[t].index + c]];
    out = sq_mesh_from_arrays(n, x, m->ntets, tets, m->source, err);
done:
    free(seen);
    free(order);
    free(tmp);
    free(nb);
    free(newid);
    free(x);
    free(tets);
    free(tk);
    return out;
}
