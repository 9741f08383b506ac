/*
 * The problems the fitting tests are built on (fit_cases.c): random example poses for any test, and
 * for test_fit.c a generated animation-space model with its exact examples, the terms of the fits'
 * objectives and plain-loop references to compare the solvers with.
 */
#ifndef SKINKIT_FIT_CASES_H
#define SKINKIT_FIT_CASES_H

#include <stddef.h>
#include <stdint.h>

#include "skinkit.h"

typedef struct fit_model {
    size_t vertex_count, influence_count, bone_count, example_count;
    int32_t *offsets;     /* vertex_count + 1, exactly sized */
    int32_t *bones;       /* influence_count, exactly sized */
    double *coordinates;  /* the true p: 4 per influence, each vertex's weights summing to 1 */
    double *poses;        /* example_count * bone_count 4x4 (G_j^e) */
    double *examples;     /* example_count * vertex_count * 3 */
    sk_influences influences;   /* offsets and bones with their counts */
    sk_examples example_set;    /* poses and examples with their counts */
} fit_model;


/* Solves a x = b in place by Gaussian elimination with partial pivoting (a n x n, destroyed); 0 on a zero pivot. */
int solve_gauss(double *a, double *b, size_t n);

/* example_count poses of bone_count bones: bone 0 the identity root, the others random affine. */
double *random_example_poses(size_t example_count, size_t bone_count);

/* A random model with 1 .. max_influences bones per vertex (bone 0 only when allow_root) and exact examples. */
fit_model make_fit_model(size_t vertex_count, size_t bone_count, size_t example_count, size_t max_influences,
                         int allow_root);
void free_fit_model(fit_model *m);
void add_noise(double *values, size_t count, double amplitude);

double data_term(const fit_model *m, const double *coordinates); /* sum_i sum_e |G^e p_i - v_i^e|^2 */
double edge_term(const fit_model *m, const double *coordinates, const int32_t *edges, const double *weights,
                 size_t edge_count); /* sum_edges w_k |p_a - p_b|^2 */
double worst_weight_sum_error(const fit_model *m, const double *coordinates);

/* References by Gaussian elimination of the KKT systems; 0 if a system is singular. */
int reference_per_vertex(double *coordinates, const fit_model *m, double lambda);
int reference_global(double *coordinates, const fit_model *m, const int32_t *edges, const double *weights,
                     size_t edge_count);

#endif
