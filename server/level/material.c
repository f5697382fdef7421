/* material.c - elastic material in the standard Lamé names: conversions and range checks. */
#include <math.h>
#include <string.h>

#include "level/level.h"

sq_material sq_material_paper(void)
{
    sq_material m;
    memset(&m, 0, sizeof m);
    m.mu = 40000;
    m.lambda = 100000;
    m.density = 1000;
    return m;
}

int sq_material_from_E_nu(sq_material *m, double E, double nu, sq_err *err)
{
    if (!isfinite(E) || E <= 0)
        return sq_err_set(err, "Young's modulus E=%g Pa is out of range: give a finite value > 0 "
                               "(soft tissue ~1e3..1e5 Pa, rubber ~1e6 Pa)", E);
    if (!isfinite(nu) || nu < 0 || nu >= 0.5)
        return sq_err_set(err, "Poisson ratio nu=%g is out of range: give 0 <= nu < 0.5 "
                               "(0.5 is incompressible, which linear tets cannot simulate)", nu);
    m->mu = E / (2.0 * (1.0 + nu));
    m->lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    return 0;
}

void sq_material_E_nu(const sq_material *m, double *E, double *nu)
{
    double s = m->lambda + m->mu;
    if (E)
        *E = s != 0 ? m->mu * (3.0 * m->lambda + 2.0 * m->mu) / s : 0;
    if (nu)
        *nu = s != 0 ? m->lambda / (2.0 * s) : 0;
}

int sq_material_check(const sq_material *m, sq_err *err)
{
    if (!isfinite(m->mu) || m->mu <= 0)
        return sq_err_set(err, "shear modulus mu=%g Pa is out of range: give a finite value > 0", m->mu);
    if (!isfinite(m->lambda) || m->lambda < 0)
        return sq_err_set(err, "Lame parameter lambda=%g Pa is out of range: give a finite value >= 0 "
                               "(lambda < 0 means nu < 0, which is not supported)", m->lambda);
    if (!isfinite(m->density) || m->density <= 0)
        return sq_err_set(err, "density=%g kg/m^3 is out of range: give a finite value > 0 "
                               "(water is 1000)", m->density);
    if (!isfinite(m->rayleigh_mass) || m->rayleigh_mass < 0)
        return sq_err_set(err, "rayleigh_mass=%g 1/s is out of range: give a finite value >= 0",
                          m->rayleigh_mass);
    if (!isfinite(m->rayleigh_stiffness) || m->rayleigh_stiffness < 0)
        return sq_err_set(err, "rayleigh_stiffness=%g s is out of range: give a finite value >= 0",
                          m->rayleigh_stiffness);
    if (m->use_viscosity) {
        if (!isfinite(m->phi) || m->phi < 0)
            return sq_err_set(err, "viscosity phi=%g Pa s is out of range: give a finite value >= 0", m->phi);
        if (!isfinite(m->psi) || m->psi < 0)
            return sq_err_set(err, "viscosity psi=%g Pa s is out of range: give a finite value >= 0", m->psi);
    }
    return 0;
}
