/* The vessel wall as a distance field: a contact test for wire capsules in compiled code.

   The wall of prisms costs a physics step most of its collision time: MuJoCo's midphase
   pairs each wire capsule with the dozens of prisms whose boxes overlap it inside the
   tube, and runs a convex test per pair (docs/speed.md, "Collision study"). Here the wall
   is one geom of type SDF whose contact with a capsule (or sphere) is a lookup in a
   sampled signed distance to the lumen surface: a few microseconds per capsule.

   The field lives in the model itself, in a custom numeric field named like the wall
   geom, so it travels with copies and saved models. Layout (all mjtNum):
     [0] FIELD_MAGIC, [1] node spacing h (m), [2..4] world position of node (0,0,0) (m),
     [5..7] blocks along x, y, z, [8] shift (m), [9..11] reserved,
     then one entry per block (its number, or -1 where no node lies near the wall),
     then 8x8x8 node values per numbered block, x fastest: the signed distance to the
     lumen surface in metres, positive inside the lumen; NaN where a node lies further
     than the band from the wall (no contact can arise there).
   The wall geom must be static in the world body: the field is in world coordinates.

   A capsule's axis is sampled every SAMPLE_SPACING_M; a contact is made at each end whose
   clearance is under the margin and at each interior local minimum deeper than both
   ends (by INTERIOR_DEPTH_M: a capsule lying flat has only its two end contacts),
   refined by a parabola through its neighbours, at most MAX_CONTACTS per capsule.
   The reported distance is measured to the lumen moved out by `shift`, as the prisms
   are moved out by the contact margin, so MuJoCo's margin logic acts on the lumen.
*/
#include <math.h>
#include <string.h>

#include <mujoco/mujoco.h>

#define FIELD_MAGIC 7.07e6
#define HEADER 12
#define BLOCK 8
#define BLOCK_NODES (BLOCK * BLOCK * BLOCK)
#define SAMPLE_SPACING_M 1e-3
#define MAX_SAMPLES 64
#define MAX_CONTACTS 4
#define INTERIOR_DEPTH_M 1e-5  /* an interior minimum counts if this much deeper than both ends */

static mjfCollision original[mjNGEOMTYPES];
static int installed = 0;

/* ---------------------------------------------------------------- field lookup */

typedef struct {
  const mjtNum* index;
  const mjtNum* data;
  mjtNum h, origin[3], shift;
  int nb[3];
} Field;

static int field_view(const mjtNum* raw, Field* f) {
  if (raw[0] != FIELD_MAGIC) return 0;
  f->h = raw[1];
  for (int i = 0; i < 3; i++) {
    f->origin[i] = raw[2 + i];
    f->nb[i] = (int)raw[5 + i];
  }
  f->shift = raw[8];
  f->index = raw + HEADER;
  f->data = f->index + (size_t)f->nb[0] * f->nb[1] * f->nb[2];
  return 1;
}

static const mjtNum* field_of(const mjModel* m, int geom) {
  const char* name = m->names + m->name_geomadr[geom];
  for (int k = 0; k < m->nnumeric; k++) {
    if (m->numeric_size[k] > HEADER && !strcmp(m->names + m->name_numericadr[k], name)) {
      const mjtNum* raw = m->numeric_data + m->numeric_adr[k];
      return raw[0] == FIELD_MAGIC ? raw : NULL;
    }
  }
  return NULL;
}

/* Value at integer node (i, j, k); NaN outside the stored band. */
static mjtNum node(const Field* f, int i, int j, int k) {
  if (i < 0 || j < 0 || k < 0) return NAN;
  int bi = i / BLOCK, bj = j / BLOCK, bk = k / BLOCK;
  if (bi >= f->nb[0] || bj >= f->nb[1] || bk >= f->nb[2]) return NAN;
  int b = (int)f->index[((size_t)bk * f->nb[1] + bj) * f->nb[0] + bi];
  if (b < 0) return NAN;
  return f->data[(size_t)b * BLOCK_NODES + ((k % BLOCK) * BLOCK + (j % BLOCK)) * BLOCK + (i % BLOCK)];
}

/* Trilinear value and gradient at world point p; returns 0 where any corner is unknown. */
static int sample(const Field* f, const mjtNum p[3], mjtNum* value, mjtNum grad[3]) {
  mjtNum u[3];
  int c[3];
  for (int a = 0; a < 3; a++) {
    mjtNum x = (p[a] - f->origin[a]) / f->h;
    mjtNum fl = floor(x);
    c[a] = (int)fl;
    u[a] = x - fl;
  }
  mjtNum v[8];
  for (int n = 0; n < 8; n++) {
    v[n] = node(f, c[0] + (n & 1), c[1] + ((n >> 1) & 1), c[2] + ((n >> 2) & 1));
    if (isnan(v[n])) return 0;
  }
  mjtNum x0 = 1 - u[0], y0 = 1 - u[1], z0 = 1 - u[2];
  mjtNum vx00 = v[0] * x0 + v[1] * u[0], vx10 = v[2] * x0 + v[3] * u[0];
  mjtNum vx01 = v[4] * x0 + v[5] * u[0], vx11 = v[6] * x0 + v[7] * u[0];
  mjtNum vy0 = vx00 * y0 + vx10 * u[1], vy1 = vx01 * y0 + vx11 * u[1];
  *value = vy0 * z0 + vy1 * u[2];
  if (grad) {
    mjtNum dx00 = v[1] - v[0], dx10 = v[3] - v[2], dx01 = v[5] - v[4], dx11 = v[7] - v[6];
    grad[0] = ((dx00 * y0 + dx10 * u[1]) * z0 + (dx01 * y0 + dx11 * u[1]) * u[2]) / f->h;
    grad[1] = ((vx10 - vx00) * z0 + (vx11 - vx01) * u[2]) / f->h;
    grad[2] = (vy1 - vy0) / f->h;
  }
  return 1;
}

/* ---------------------------------------------------------------- contact */

static int make_contact(const Field* f, const mjtNum p[3], mjtNum radius, mjtNum margin,
                        mjPreContact* con) {
  mjtNum d, g[3];
  if (!sample(f, p, &d, g)) return 0;
  mjtNum dist = d + f->shift - radius;
  if (dist >= margin) return 0;
  mjtNum norm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
  if (norm < 1e-9) return 0;
  /* the field grows into the lumen: the wall lies against its gradient */
  for (int a = 0; a < 3; a++) {
    con->normal[a] = -g[a] / norm;
    con->pos[a] = p[a] + con->normal[a] * (radius + 0.5 * dist);
    con->tangent[a] = 0;
  }
  con->dist = dist;
  return 1;
}

int cathsim_wall_collide(const mjModel* m, mjData* d, mjPreContact* con, int g1, int g2,
                         mjtNum margin) {
  const mjtNum* raw = field_of(m, g2);
  int type = m->geom_type[g1];
  if (!raw || (type != mjGEOM_CAPSULE && type != mjGEOM_SPHERE)) {
    return original[type] ? original[type](m, d, con, g1, g2, margin) : 0;
  }
  Field f;
  field_view(raw, &f);
  const mjtNum* centre = d->geom_xpos + 3 * g1;
  const mjtNum* mat = d->geom_xmat + 9 * g1;
  mjtNum radius = m->geom_size[3 * g1];
  mjtNum half = type == mjGEOM_CAPSULE ? m->geom_size[3 * g1 + 1] : 0;
  mjtNum axis[3] = {mat[2], mat[5], mat[8]};

  int n = half > 0 ? (int)ceil(2 * half / SAMPLE_SPACING_M) + 1 : 1;
  if (n > MAX_SAMPLES) n = MAX_SAMPLES;
  if (n == 2) n = 3;  /* an interior sample, so that a middle minimum can show */
  mjtNum t[MAX_SAMPLES], s[MAX_SAMPLES];
  int known[MAX_SAMPLES];
  for (int i = 0; i < n; i++) {
    t[i] = n > 1 ? -half + 2 * half * i / (n - 1) : 0;
    mjtNum p[3] = {centre[0] + t[i] * axis[0], centre[1] + t[i] * axis[1], centre[2] + t[i] * axis[2]};
    known[i] = sample(&f, p, &s[i], NULL);
    if (!known[i]) s[i] = INFINITY;
  }

  /* candidate points along the axis: both ends, and interior minima deeper than both */
  mjtNum cand[MAX_SAMPLES];
  mjtNum depth[MAX_SAMPLES];
  int ncand = 0;
  cand[ncand] = t[0], depth[ncand++] = s[0];
  if (n > 1) cand[ncand] = t[n - 1], depth[ncand++] = s[n - 1];
  mjtNum ends = n > 1 ? fmin(s[0], s[n - 1]) : s[0];
  for (int i = 1; i < n - 1; i++) {
    if (!(s[i] < s[i - 1] && s[i] <= s[i + 1] && s[i] < ends - INTERIOR_DEPTH_M)) continue;
    mjtNum curvature = s[i - 1] - 2 * s[i] + s[i + 1];
    mjtNum step = t[1] - t[0];
    /* a neighbour outside the stored band (infinite) leaves the sample where it is */
    mjtNum offset = curvature > 0 && isfinite(curvature) ? 0.5 * (s[i - 1] - s[i + 1]) / curvature : 0;
    if (offset > 0.5) offset = 0.5;
    if (offset < -0.5) offset = -0.5;
    cand[ncand] = t[i] + offset * step, depth[ncand++] = s[i];
  }

  /* the deepest first, at most MAX_CONTACTS and what the buffer holds */
  int limit = MAX_CONTACTS < m->opt.sdf_initpoints ? MAX_CONTACTS : m->opt.sdf_initpoints;
  int ncon = 0;
  while (ncon < limit) {
    int best = -1;
    for (int i = 0; i < ncand; i++) {
      if (isfinite(depth[i]) && (best < 0 || depth[i] < depth[best])) best = i;
    }
    if (best < 0) break;
    depth[best] = INFINITY;
    mjtNum p[3] = {centre[0] + cand[best] * axis[0], centre[1] + cand[best] * axis[1],
                   centre[2] + cand[best] * axis[2]};
    ncon += make_contact(&f, p, radius, margin, con + ncon);
  }
  return ncon;
}

/* ---------------------------------------------------------------- installation */

/* Routes every geom type's collision with SDF geoms through cathsim_wall_collide, which
   hands geoms without a field back to MuJoCo's own function. `table` is MuJoCo's
   mjCOLLISIONFUNC. Returns 1 when newly installed, 0 when it already was. */
int cathsim_wall_install(mjfCollision* table) {
  if (installed) return 0;
  for (int type = 0; type < mjNGEOMTYPES; type++) {
    original[type] = table[type * mjNGEOMTYPES + mjGEOM_SDF];
    if (original[type]) table[type * mjNGEOMTYPES + mjGEOM_SDF] = cathsim_wall_collide;
  }
  installed = 1;
  return 1;
}

/* Field value at a world point (NaN where unknown), for tests and tools. */
double cathsim_wall_distance(const double* raw, const double* p) {
  Field f;
  mjtNum value;
  if (!field_view(raw, &f) || !sample(&f, p, &value, NULL)) return NAN;
  return value;
}

/* ---------------------------------------------------------------- building the field */

/* q = from + t * dir (3-vectors). */
static void point_along(double* q, const double* from, const double* dir, double t) {
  for (int i = 0; i < 3; i++) q[i] = from[i] + t * dir[i];
}

static double dot3(const double* u, const double* v) { return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]; }

/* Closest point on triangle (a, b, c) to p (Ericson, Real-Time Collision Detection 5.1.5).
   `feature`: 0 face, 1-3 vertex a/b/c, 4 edge ab, 5 edge bc, 6 edge ca. */
static void closest_on_triangle(const double* p, const double* a, const double* b, const double* c,
                                double* q, int* feature) {
  double ab[3], ac[3], bc[3], ap[3], bp[3], cp[3];
  for (int i = 0; i < 3; i++) {
    ab[i] = b[i] - a[i], ac[i] = c[i] - a[i], bc[i] = c[i] - b[i];
    ap[i] = p[i] - a[i], bp[i] = p[i] - b[i], cp[i] = p[i] - c[i];
  }
  double d1 = dot3(ab, ap), d2 = dot3(ac, ap);
  if (d1 <= 0 && d2 <= 0) { point_along(q, a, ab, 0), *feature = 1; return; }
  double d3 = dot3(ab, bp), d4 = dot3(ac, bp);
  if (d3 >= 0 && d4 <= d3) { point_along(q, b, ab, 0), *feature = 2; return; }
  double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) { point_along(q, a, ab, d1 / (d1 - d3)), *feature = 4; return; }
  double d5 = dot3(ab, cp), d6 = dot3(ac, cp);
  if (d6 >= 0 && d5 <= d6) { point_along(q, c, ab, 0), *feature = 3; return; }
  double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) { point_along(q, a, ac, d2 / (d2 - d6)), *feature = 6; return; }
  double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    point_along(q, b, bc, (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    *feature = 5;
    return;
  }
  double denom = 1.0 / (va + vb + vc);
  double v = vb * denom, w = vc * denom;
  for (int i = 0; i < 3; i++) q[i] = a[i] + ab[i] * v + ac[i] * w;
  *feature = 0;
}

/* The node index range [first, last] (per axis) of triangle v's box grown by `band`. */
static void triangle_nodes(const double* v, double band, const double* origin, double h, const int* nb,
                           int* first, int* last) {
  for (int a = 0; a < 3; a++) {
    double lo = fmin(v[a], fmin(v[3 + a], v[6 + a])) - band;
    double hi = fmax(v[a], fmax(v[3 + a], v[6 + a])) + band;
    first[a] = (int)ceil((lo - origin[a]) / h);
    last[a] = (int)floor((hi - origin[a]) / h);
    if (first[a] < 0) first[a] = 0;
    if (last[a] > nb[a] * BLOCK - 1) last[a] = nb[a] * BLOCK - 1;
  }
}

/* Marks (index = 1) every block holding a node within `band` of a triangle's box. */
void cathsim_wall_mark_blocks(int ntri, const double* tri, double h, const double* origin,
                              const int* nb, double band, double* index) {
  for (int t = 0; t < ntri; t++) {
    int first[3], last[3];
    triangle_nodes(tri + 9 * t, band, origin, h, nb, first, last);
    for (int k = first[2] / BLOCK; k <= last[2] / BLOCK; k++)
      for (int j = first[1] / BLOCK; j <= last[1] / BLOCK; j++)
        for (int i = first[0] / BLOCK; i <= last[0] / BLOCK; i++)
          index[((size_t)k * nb[1] + j) * nb[0] + i] = 1;
  }
}

/* Signed distance to the lumen at every node within `band` of it (others stay NaN).
   `normals` holds per triangle the outward face normal, then the pseudo-normals of its
   vertices a, b, c and of its edges ab, bc, ca (7 x 3): the sign of the nearest
   feature's pseudo-normal decides inside or outside (Baerentzen and Aanaes 2005). Nodes
   on the outer side of `cut` (a point and an outward normal: the open end) stay NaN. */
void cathsim_wall_fill(int ntri, const double* tri, const double* normals, double h,
                       const double* origin, const int* nb, double band, const double* index,
                       const double* cut, double* data, double* best) {
  for (int t = 0; t < ntri; t++) {
    const double* v = tri + 9 * t;
    const double* nrm = normals + 21 * t;
    int first[3], last[3];
    triangle_nodes(v, band, origin, h, nb, first, last);
    for (int k = first[2]; k <= last[2]; k++)
      for (int j = first[1]; j <= last[1]; j++)
        for (int i = first[0]; i <= last[0]; i++) {
          int b = (int)index[((size_t)(k / BLOCK) * nb[1] + j / BLOCK) * nb[0] + i / BLOCK];
          if (b < 0) continue;
          size_t at = (size_t)b * BLOCK_NODES + ((k % BLOCK) * BLOCK + (j % BLOCK)) * BLOCK + (i % BLOCK);
          double p[3] = {origin[0] + i * h, origin[1] + j * h, origin[2] + k * h};
          if (cut && (p[0] - cut[0]) * cut[3] + (p[1] - cut[1]) * cut[4] + (p[2] - cut[2]) * cut[5] > 0)
            continue;
          double q[3];
          int feature;
          closest_on_triangle(p, v, v + 3, v + 6, q, &feature);
          double r[3] = {p[0] - q[0], p[1] - q[1], p[2] - q[2]};
          double dist2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
          if (dist2 > band * band || dist2 >= best[at]) continue;
          best[at] = dist2;
          const double* pn = nrm + 3 * (feature == 0 ? 0 : feature);  /* 1-3 vertices, 4-6 edges */
          double side = r[0] * pn[0] + r[1] * pn[1] + r[2] * pn[2];
          data[at] = side > 0 ? -sqrt(dist2) : sqrt(dist2);
        }
  }
}
