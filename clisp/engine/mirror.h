/* The CFA-phase preserving mirror of the tile windows (clisp/engine/tiling.py: cfa_mirror_index),
 * shared by the device gather (gather.cl) and the stages that pad what they corrected (sensor.cl);
 * included once per program (no guard: tools/check_layout.py allows no #ifndef). */
/* cfa_mirror: tiling.cfa_mirror_index for one index: i inside [0, n) unchanged; outside, the
 * whole-sample reflection (-1 -> 1, n -> n-2), then the nearest index congruent to i modulo
 * period, so the padded sample keeps its CFA colour. Needs n >= period, n >= 2. */
inline int cfa_mirror(const int i, const int n, const int period)
{
    if (i >= 0 && i < n)
        return i;
    const int cycle = 2 * n - 2;
    int m = abs(i) % cycle;
    if (m >= n)
        m = cycle - m;
    const int delta = ((i - m) % period + period) % period;
    const int up = m + delta;
    const int down = up - period;
    return ((delta <= period / 2 && up < n) || down < 0) ? up : down;
}
