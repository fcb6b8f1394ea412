// iridescent_layer_tables.h -- DEFAULT constant tables of iridescent_layer.osl: one 200 µm scratch
// (W = 2 µm, D = 1 µm) across the middle of UV space, a sphere light and a two-sided triangle light
// (route B), made by osl/iridescent_layer.py, so that the .osl file compiles on its own.  The generator
// replaces this include by the material's tables (same names).

    float SEG[14] = {
        1, 0, 4900, 5000, 200, 2, 9.04236686e-07, 1.56470571e-06,
        2.18736341e-06, 4.65630592e-06, 0.0132980756, 0.000969141547, 0.0023517739, 0.0043032961
    };
    int CSTART[7] = {
        0, 1, 2, 3, 4, 5, 5
    };
    int CITEMS[5] = {
        1073741823, 1073741823, 1073741823, 1073741823, 1073741823
    };
    float LAM[3] = {0.63, 0.532, 0.465};
    float KL[3] = {9.97331001, 11.8104987, 13.5122265};
#if NSPH
    float SPH[7] = {
        0, 0, 2, 0.1, 10, 10, 10
    };
#endif
#if NPOLY
    int PSTART[2] = {
        0, 3
    };
    float PVERT[9] = {
        -0.5, -0.5, 2, 0.5, -0.5, 2, 0, 0.5,
        2
    };
    float PRAD[3] = {
        5, 5, 5
    };
    int PTWO[1] = {
        1
    };
#endif
