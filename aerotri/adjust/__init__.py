"""Bundle block adjustment with GNSS and ground control (GTSAM factor graph), ISAT-style reports.

Modules, one concept each: ``local_frame`` (tangent-plane frame), ``observations`` (CSV readers and
validation), ``strips`` (strips from the GNSS track), ``approximate`` (initial exterior orientation),
``keys`` (the gtsam symbols of the unknowns), ``collinearity`` (the collinearity equations with Cal3DS2
over arrays), ``graph`` (the GTSAM factor graph), ``schur`` (tie points eliminated by the
Schur complement: the reduced camera system, linearised in numba), ``datum`` (the block moved by a
similarity onto its control points: the datum step of blocks without GNSS), ``snooping`` (data snooping),
``solve`` (robust solution, snooping and control-point tests, final least squares),
``covariance`` (a-posteriori covariances from the reduced camera system), ``check_points``
(multi-ray intersection), ``report`` (txt/json/html), ``export`` (PATB, COLMAP), ``pipeline`` (the
``adjust`` stage over a project folder), ``cli`` (the click command).
"""
