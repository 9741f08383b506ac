/* The mesh with metric edge lengths, marks, the chart metric of eq. 5.4 and the disc check (sk_charts.h). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_charts.h"

/* A chart whose projected area vanishes (folded flat onto itself) gets this finite area ratio, so that
 * sums of chart costs never meet inf - inf and such charts still merge last. */
#define MAX_AREA_RATIO 1e12
#define SK_PI 3.14159265358979323846

/* ---------------------------------------------------------------------------------------------
 * Mesh topology: the shared edge flaps (common/sk_mesh.h) and metric edge lengths
 * ------------------------------------------------------------------------------------------- */

void sk_free_topology(topology *mesh)
{
    sk_edge_flaps_free(&mesh->flaps);
    free(mesh->edge_lengths);
    mesh->edge_lengths = NULL;
}

static double distance(const double *embedding, size_t dimension, int32_t u, int32_t v)
{
    double sum = 0.0;
    for (size_t k = 0; k < dimension; ++k) {
        const double difference = embedding[(size_t)u * dimension + k] - embedding[(size_t)v * dimension + k];
        sum += difference * difference;
    }
    return sqrt(sum);
}

/* Validates the triangles and builds the topology; a non-manifold edge is refused by name. */
sk_status sk_build_topology(topology *mesh, const int32_t *triangles, size_t vertex_count, size_t triangle_count,
                                const double *embedding, size_t dimension, sk_error *error)
{
    memset(mesh, 0, sizeof *mesh);
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3 || vertex_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "need between 1 and %d triangles and fewer than 2^31 vertices",
                       INT32_MAX / 3);
    const sk_triangle_mesh given = {triangles, triangle_count, vertex_count};
    sk_status status = sk_validate_triangles(&given, error);
    if (status != SK_OK)
        return status;
    sk_edge_defect defect;
    status = sk_edge_flaps_build(&mesh->flaps, triangles, triangle_count, vertex_count, &defect);
    if (status == SK_ERROR_ARGUMENT)
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "edge (%d, %d) is shared by %zu triangles (%d, %d, %d...): the mesh is not manifold",
                       defect.vertices[0], defect.vertices[1], defect.triangle_count, defect.triangles[0],
                       defect.triangles[1], defect.triangles[2]);
    if (status != SK_OK)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for the mesh edges of %zu triangles", triangle_count);
    if (embedding) {
        const size_t E = mesh->flaps.edge_count;
        mesh->edge_lengths = sk_allocate(E, sizeof(double));
        if (!mesh->edge_lengths)
            return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu edge lengths", E);
        for (size_t e = 0; e < E; ++e)
            mesh->edge_lengths[e] =
                distance(embedding, dimension, mesh->flaps.edge_vertices[2 * e], mesh->flaps.edge_vertices[2 * e + 1]);
    }
    return SK_OK;
}

/* Refuses an embedding whose size overflows, or with a NaN or infinity (naming the vertex). */
sk_status sk_check_embedding(const double *embedding, size_t dimension, size_t vertex_count, sk_error *error)
{
    size_t values;
    const sk_status status = sk_array_size(&values, vertex_count, dimension, 1, "embedding", error);
    if (status != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(embedding, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "embedding of vertex %zu has a NaN or infinity", bad / dimension);
    return SK_OK;
}

/* ---------------------------------------------------------------------------------------------
 * Scratch: per-vertex and per-triangle marks that are "cleared" by bumping a generation counter
 * ------------------------------------------------------------------------------------------- */

int sk_make_marks(marks *m, size_t count)
{
    m->generation = 0;
    m->stamp = sk_allocate_zeroed(count + 1, sizeof *m->stamp);
    m->value = sk_allocate_zeroed(3 * (count + 1), sizeof *m->value);
    return m->stamp && m->value;
}

void sk_free_marks(marks *m)
{
    free(m->stamp);
    free(m->value);
}

/* ---------------------------------------------------------------------------------------------
 * Chart metric (eq. 5.4): area, summed bivector, perimeter
 * ------------------------------------------------------------------------------------------- */

void sk_triangle_bivector(double *bivector, double *area, const double *embedding, size_t dimension,
                              const int32_t *triangle)
{
    const double *a = embedding + (size_t)triangle[0] * dimension, *b = embedding + (size_t)triangle[1] * dimension,
                 *c = embedding + (size_t)triangle[2] * dimension;
    double sum = 0.0;
    size_t k = 0;
    for (size_t i = 0; i < dimension; ++i)
        for (size_t j = i + 1; j < dimension; ++j, ++k) {
            const double u_i = b[i] - a[i], u_j = b[j] - a[j], v_i = c[i] - a[i], v_j = c[j] - a[j];
            bivector[k] = 0.5 * (u_i * v_j - u_j * v_i);
            sum += bivector[k] * bivector[k];
        }
    *area = sqrt(sum);
}

/*
 * Maximum projected area = the spectral norm of the antisymmetric matrix M of the bivector. Its singular
 * values come in equal pairs, so in 2-4 dimensions there are closed forms (|B|; for d = 4 the pair's
 * squares are the roots of s^2 - |B|^2 s + Pf(M)^2). Beyond that we take the largest eigenvalue of
 * M^T M with LAPACK dsyevr rather than power iteration: the top eigenvalue is always double and the
 * next pair is close to it exactly for the tube-like charts the metric must recognise, where power
 * iteration would converge slowly and stop early with an underestimate.
 */
double sk_max_projected_area(spectral_workspace *w, const double *bivector)
{
    const size_t d = w->dimension;
    double squared = 0.0;
    for (size_t k = 0; k < d * (d - 1) / 2; ++k)
        squared += bivector[k] * bivector[k];
    if (d <= 3)
        return sqrt(squared);
    if (d == 4) {
        const double pfaffian = bivector[0] * bivector[5] - bivector[1] * bivector[4] + bivector[2] * bivector[3];
        const double discriminant = fmax(squared * squared - 4.0 * pfaffian * pfaffian, 0.0);
        return sqrt(0.5 * (squared + sqrt(discriminant)));
    }
    double m[SK_SEGMENT_MAX_DIMENSION * SK_SEGMENT_MAX_DIMENSION] = {0};
    for (size_t i = 0, k = 0; i < d; ++i)
        for (size_t j = i + 1; j < d; ++j, ++k) {
            m[i * d + j] = bivector[k];
            m[j * d + i] = -bivector[k];
        }
    for (size_t i = 0; i < d; ++i)
        for (size_t j = 0; j < d; ++j) {
            double sum = 0.0;
            for (size_t k = 0; k < d; ++k)
                sum += m[k * d + i] * m[k * d + j];
            w->matrix[j * d + i] = sum;
        }
    lapack_int found = 0;
    double eigenvalue[SK_SEGMENT_MAX_DIMENSION];
    const lapack_int n = (lapack_int)d;
    /* Column-major _work variant: M^T M is symmetric, and the plain driver would allocate on every call. */
    const lapack_int info = LAPACKE_dsyevr_work(LAPACK_COL_MAJOR, 'N', 'I', 'U', n, w->matrix, n, 0.0, 0.0, n, n,
                                                0.0, &found, eigenvalue, w->eigenvectors, n, w->support, w->work,
                                                26 * n, w->iwork, 10 * n);
    if (info != 0 || found != 1) {
        if (!w->failure)
            w->failure = info != 0 ? info : -1;
        return sqrt(squared); /* an upper bound; the caller reports the failure */
    }
    return sqrt(fmax(eigenvalue[0], 0.0));
}

/* E_combined * area (the chart's term in eq. 5.5's numerator); zero for a chart of zero area. */
double sk_weighted_metric(double area, double perimeter, double projected, double rho)
{
    if (!(area > 0.0))
        return 0.0;
    const double compactness = rho * perimeter * perimeter / (4.0 * SK_PI);
    return (area + compactness) * area / fmax(projected, area / MAX_AREA_RATIO);
}

double sk_combined_metric(double area, double perimeter, double projected, double rho)
{
    return area > 0.0 ? sk_weighted_metric(area, perimeter, projected, rho) / area : 0.0;
}

/* ---------------------------------------------------------------------------------------------
 * Charts given per triangle: member lists and the disc check
 * ------------------------------------------------------------------------------------------- */

void sk_free_members(chart_members *members)
{
    for (size_t c = 0; members->lists && c < members->chart_count; ++c)
        free(members->lists[c].items);
    free(members->lists);
    memset(members, 0, sizeof *members);
}

/* Checks the chart ids' range and lists each chart's triangles. */
sk_status sk_collect_members(chart_members *members, const int32_t *charts, size_t triangle_count, sk_error *error)
{
    memset(members, 0, sizeof *members);
    if (!charts)
        return sk_fail(error, SK_ERROR_ARGUMENT, "charts must not be null");
    size_t count = 0;
    for (size_t t = 0; t < triangle_count; ++t) {
        if (charts[t] < 0 || (size_t)charts[t] >= triangle_count)
            return sk_fail(error, SK_ERROR_INDEX, "triangle %zu: chart %d is outside [0, %zu)", t, (int)charts[t],
                           triangle_count);
        if ((size_t)charts[t] + 1 > count)
            count = (size_t)charts[t] + 1;
    }
    members->chart_count = count;
    members->lists = sk_allocate_zeroed(count, sizeof *members->lists);
    int ok = members->lists != NULL;
    for (size_t t = 0; ok && t < triangle_count; ++t)
        ok = add_member(members, charts[t], (int32_t)t);
    return ok ? SK_OK : sk_fail(error, SK_ERROR_MEMORY, "no memory for the triangle lists of %zu charts", count);
}

int sk_make_disc_scratch(disc_scratch *scratch, const topology *mesh)
{
    scratch->queue = sk_allocate(mesh->flaps.triangle_count + 1, sizeof(int32_t));
    return sk_make_marks(&scratch->vertices, mesh->flaps.vertex_count) &&
           sk_make_marks(&scratch->triangles, mesh->flaps.triangle_count) && scratch->queue;
}

void sk_free_disc_scratch(disc_scratch *scratch)
{
    sk_free_marks(&scratch->vertices);
    sk_free_marks(&scratch->triangles);
    free(scratch->queue);
}

static size_t reachable_triangles(const topology *mesh, const int32_t *charts, const int32_t *list, disc_scratch *s)
{
    next_generation(&s->triangles, mesh->flaps.triangle_count);
    size_t head = 0, tail = 0;
    mark(&s->triangles, list[0]);
    s->queue[tail++] = list[0];
    while (head < tail) {
        const int32_t t = s->queue[head++];
        for (int k = 0; k < 3; ++k) {
            const int32_t o = sk_edge_other_triangle(&mesh->flaps, mesh->flaps.triangle_edges[3 * t + k], t);
            if (o >= 0 && charts[o] == charts[t] && mark(&s->triangles, o))
                s->queue[tail++] = o;
        }
    }
    return tail;
}

/*
 * NULL when chart c (its `count` triangles in `list`) is a topological disc, else the reason. A disc is
 * connected, has Euler characteristic V - E + F = 1 and a boundary, and each vertex has one fan of chart
 * triangles (boundary vertices exactly two boundary edges): this rules out charts touching themselves at
 * a vertex, annuli, spheres and the projective plane.
 */
const char *sk_disc_problem(const topology *mesh, const int32_t *charts, int32_t c, const int32_t *list,
                                size_t count, disc_scratch *s, int32_t *where)
{
    marks *v = &s->vertices;
    next_generation(v, mesh->flaps.vertex_count);
    long vertices = 0, boundary = 0, interior_sides = 0;
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const int32_t x = mesh->flaps.triangles[3 * list[i] + k];
            vertices += mark(v, x);
            ++v->value[3 * x];
        }
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const int32_t e = mesh->flaps.triangle_edges[3 * list[i] + k];
            const int32_t o = sk_edge_other_triangle(&mesh->flaps, e, list[i]);
            const int slot = o >= 0 && charts[o] == c ? 1 : 2;
            interior_sides += slot == 1;
            boundary += slot == 2;
            ++v->value[3 * mesh->flaps.edge_vertices[2 * e] + slot];
            ++v->value[3 * mesh->flaps.edge_vertices[2 * e + 1] + slot];
        }
    *where = list[0];
    if (boundary == 0)
        return "it is a closed surface";
    if (vertices - (boundary + interior_sides / 2) + (long)count != 1)
        return "its Euler characteristic is not 1";
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const int32_t x = mesh->flaps.triangles[3 * list[i] + k];
            const int32_t fans = v->value[3 * x] - v->value[3 * x + 1] / 2, edges = v->value[3 * x + 2];
            if (!(edges == 0 ? fans == 0 : edges == 2 && fans == 1)) {
                *where = x;
                return "it touches itself at a vertex";
            }
        }
    if (reachable_triangles(mesh, charts, list, s) != count)
        return "it is not connected";
    return NULL;
}

sk_status sk_check_discs(const topology *mesh, const int32_t *charts, const chart_members *members,
                             disc_scratch *scratch, sk_error *error)
{
    for (size_t c = 0; c < members->chart_count; ++c) {
        int32_t where;
        const char *problem = members->lists[c].size ? sk_disc_problem(mesh, charts, (int32_t)c, members->lists[c].items,
                                                               members->lists[c].size, scratch, &where)
                                               : NULL;
        if (problem)
            return sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu is not a disc: %s (near %s %d)", c, problem,
                           strstr(problem, "vertex") ? "vertex" : "triangle", (int)where);
    }
    return SK_OK;
}

/* E_mesh (eq. 5.5) of charts given per triangle (ids 0..count-1): per chart its area, summed bivector and
 * perimeter (edges whose other side is another chart or nothing). Returns -1 when memory ran out. */
double sk_charts_mesh_metric(const topology *mesh, const int32_t *charts, size_t count, const double *embedding,
                                 size_t dimension, double rho)
{
    const size_t components = dimension * (dimension - 1) / 2;
    chart_shape *shapes = sk_allocate_zeroed(count, sizeof *shapes);
    if (!shapes)
        return -1.0;
    for (size_t t = 0; t < mesh->flaps.triangle_count; ++t) {
        chart_shape *shape = &shapes[charts[t]];
        double bivector[MAX_COMPONENTS], area;
        sk_triangle_bivector(bivector, &area, embedding, dimension, mesh->flaps.triangles + 3 * t);
        shape->area += area;
        for (size_t k = 0; k < components; ++k)
            shape->bivector[k] += bivector[k];
        for (int k = 0; k < 3; ++k) {
            const int32_t e = mesh->flaps.triangle_edges[3 * t + k], o = sk_edge_other_triangle(&mesh->flaps, e, (int32_t)t);
            if (o < 0 || charts[o] != charts[t])
                shape->perimeter += mesh->edge_lengths[e];
        }
    }
    spectral_workspace spectral;
    memset(&spectral, 0, sizeof spectral);
    spectral.dimension = dimension;
    double sum = 0.0, total_area = 0.0;
    for (size_t c = 0; c < count; ++c) {
        sum += sk_weighted_metric(shapes[c].area, shapes[c].perimeter, sk_max_projected_area(&spectral, shapes[c].bivector),
                               rho);
        total_area += shapes[c].area;
    }
    free(shapes);
    return total_area > 0.0 ? sum / total_area : 0.0;
}
