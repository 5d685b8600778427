/*
 * rosenbrock.c -- fixed-step L-stable linearly-implicit integrator for small dense systems.
 *
 * ROS34PW2 (J. Rang and L. Angermann, "New Rosenbrock W-methods of order 3 for partial
 * differential algebraic equations of index 1", BIT Numer. Math. 45, 2005): a 4-stage
 * Rosenbrock-W method of order 3, L-stable and stiffly accurate. For x' = f(x), with
 * W = I - gamma h J:
 *
 *     W k_i = h f(x + sum_{j<i} a_ij k_j) + h J sum_{j<i} g_ij k_j,   i = 1..4
 *     x_{n+1} = x_n + sum_i b_i k_i
 *
 * As a W-method it keeps order 3 for any matrix J, so the forward-difference Jacobian costs no
 * accuracy, and one J (and W factorised) serves up to FW_JACOBIAN_STEPS internal steps;
 * L-stability damps stiff pressure dynamics and steep regularisations (orifice square
 * root near zero pressure drop, friction tanh) instead of letting them ring or blow up.
 * J is built column by column, W factorised by Gaussian elimination with partial pivoting.
 */
#include <float.h>
#include <math.h>
#include <string.h>

#include "fmu_framework.h"

/* ROS34PW2 coefficients (Rang and Angermann 2005). */
#define STAGES 4
static const double GAMMA = 4.3586652150845900e-1;
static const double A[STAGES][STAGES] = {
    {0.0, 0.0, 0.0, 0.0},
    {8.7173304301691801e-1, 0.0, 0.0, 0.0},
    {8.4457060015369423e-1, -1.1299064236484185e-1, 0.0, 0.0},
    {0.0, 0.0, 1.0, 0.0},
};
static const double G[STAGES][STAGES] = {
    {0.0, 0.0, 0.0, 0.0},
    {-8.7173304301691801e-1, 0.0, 0.0, 0.0},
    {-9.0338057013044082e-1, 5.4180672388095326e-2, 0.0, 0.0},
    {2.4212380706095346e-1, -1.2232505839045147, 5.4526025533510214e-1, 0.0},
};
static const double B[STAGES] = {2.4212380706095346e-1, -1.2232505839045147,
                                 1.5452602553351020, 4.3586652150845900e-1};

/* LU factorisation P a = L U in place (unit L below the diagonal, U on and above), swapping
 * whole rows; pivot[k] is the row swapped with row k at step k. Returns -1 if singular. */
static int lu_factor(double a[N_STATES][N_STATES], int pivot[N_STATES]) {
    for (int k = 0; k < N_STATES; k++) {
        int p = k;
        double largest = fabs(a[k][k]);
        for (int i = k + 1; i < N_STATES; i++) {
            if (fabs(a[i][k]) > largest) {
                largest = fabs(a[i][k]);
                p = i;
            }
        }
        if (largest == 0.0 || !isfinite(largest)) return -1;
        pivot[k] = p;
        if (p != k) {
            double row[N_STATES];
            memcpy(row, a[k], sizeof row);
            memcpy(a[k], a[p], sizeof row);
            memcpy(a[p], row, sizeof row);
        }
        for (int i = k + 1; i < N_STATES; i++) {
            const double factor = a[i][k] / a[k][k];
            a[i][k] = factor;
            for (int j = k + 1; j < N_STATES; j++) a[i][j] -= factor * a[k][j];
        }
    }
    return 0;
}

/* Solve A z = b in place in b, with P A = L U from lu_factor: permute, then substitute. */
static void lu_solve(double lu[N_STATES][N_STATES], const int pivot[N_STATES], double b[N_STATES]) {
    for (int k = 0; k < N_STATES; k++) {
        const int p = pivot[k];
        if (p != k) {
            const double t = b[k];
            b[k] = b[p];
            b[p] = t;
        }
    }
    for (int k = 0; k < N_STATES; k++) {
        for (int i = k + 1; i < N_STATES; i++) b[i] -= lu[i][k] * b[k];
    }
    for (int i = N_STATES - 1; i >= 0; i--) {
        double s = b[i];
        for (int j = i + 1; j < N_STATES; j++) s -= lu[i][j] * b[j];
        b[i] = s / lu[i][i];
    }
}

/* J by forward differences at x, column by column (f0 = f(x)); W = I - gamma h J factorised. */
static int iteration_matrix(const SimData *d, const double x[N_STATES], const double f0[N_STATES],
                            double h, FwIteration *it) {
    double probe[N_STATES], fp[N_STATES];
    const double root_eps = sqrt(DBL_EPSILON);

    memcpy(probe, x, sizeof probe);
    for (int j = 0; j < N_STATES; j++) {
        const double scale = fmax(fabs(x[j]), model_state_nominal[j]);
        probe[j] = x[j] + root_eps * scale;
        const double delta = probe[j] - x[j]; /* the increment actually represented */
        model_derivatives(d, probe, fp);
        probe[j] = x[j];
        for (int i = 0; i < N_STATES; i++) {
            it->jac[i][j] = (fp[i] - f0[i]) / delta;
            it->lu[i][j] = -GAMMA * h * it->jac[i][j];
        }
        it->lu[j][j] += 1.0;
    }
    it->h = h;
    it->fresh = 0;
    it->served = 0;
    return lu_factor(it->lu, it->pivot);
}

int fw_rosenbrock_step(const SimData *d, double x[N_STATES], double h, FwIteration *it) {
    double k[STAGES][N_STATES], f0[N_STATES], probe[N_STATES], fp[N_STATES], sum[N_STATES];

    model_derivatives(d, x, f0);
    if ((it->fresh || it->h != h || it->served >= FW_JACOBIAN_STEPS) &&
        iteration_matrix(d, x, f0, h, it) != 0) {
        it->fresh = 1;
        return -1;
    }
    it->served++;

    for (int s = 0; s < STAGES; s++) {
        /* probe = x + sum a_sj k_j, sum = sum g_sj k_j */
        for (int i = 0; i < N_STATES; i++) {
            double shift = 0.0, coupling = 0.0;
            for (int j = 0; j < s; j++) {
                shift += A[s][j] * k[j][i];
                coupling += G[s][j] * k[j][i];
            }
            probe[i] = x[i] + shift;
            sum[i] = coupling;
        }
        if (s == 0) {
            memcpy(fp, f0, sizeof fp);
        } else {
            model_derivatives(d, probe, fp);
        }
        for (int i = 0; i < N_STATES; i++) {
            double js = 0.0;
            if (s > 0) { /* stage 1 has no coupling term */
                for (int j = 0; j < N_STATES; j++) js += it->jac[i][j] * sum[j];
            }
            k[s][i] = h * (fp[i] + js);
        }
        lu_solve(it->lu, it->pivot, k[s]);
    }
    for (int i = 0; i < N_STATES; i++) {
        double increment = 0.0;
        for (int s = 0; s < STAGES; s++) increment += B[s] * k[s][i];
        x[i] += increment;
    }
    return 0;
}
