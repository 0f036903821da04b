"""The approximated IK's linear programme: how to split the azimuth still to turn (rad) between the pan and the base
rotation at the least omega-weighted cost, solved by GLPK (as the original), HiGHS, or in closed form.
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.mild.config import LP_SOLVERS

__all__ = ["solve_turn_lp", "turn_split_closed_form"]


def turn_split_closed_form(alpha_rad, pan_up_rad, pan_down_rad, omega_pan: float, omega_rot: float):
    """Optimum of the approximated IK's LP, vectorised: (pan change, rotation change) in rad.

    The LP has one equality row (pan change + rotation change = alpha) and box bounds, so its optimum fills the
    cheaper variable first: the pan up to its limit when omega_pan <= omega_rot, else all of the turn by rotation
    (|alpha| <= pi fits the rotation's bound of pi).
    """
    alpha = np.asarray(alpha_rad, dtype=float)
    if omega_pan <= omega_rot:
        pan = np.clip(alpha, -np.asarray(pan_down_rad, dtype=float), np.asarray(pan_up_rad, dtype=float))
    else:
        pan = np.zeros_like(alpha)
    return pan, alpha - pan


def _solve_turn_lp_glpk(alpha: float, pan_up: float, pan_down: float, omega_pan: float, omega_rot: float):
    import swiglpk as glp

    lp = glp.glp_create_prob()
    try:
        glp.glp_set_obj_dir(lp, glp.GLP_MIN)
        glp.glp_add_cols(lp, 4)
        # x_pan+, x_pan-, x_rot+, x_rot-: all >= 0, pan bounded by the limits, rotation by pi each way
        for column, (upper, weight) in enumerate(
            ((pan_up, omega_pan), (pan_down, omega_pan), (math.pi, omega_rot), (math.pi, omega_rot)), start=1
        ):
            glp.glp_set_col_bnds(lp, column, glp.GLP_DB if upper > 0.0 else glp.GLP_FX, 0.0, max(upper, 0.0))
            glp.glp_set_obj_coef(lp, column, weight)
        glp.glp_add_rows(lp, 1)
        glp.glp_set_row_bnds(lp, 1, glp.GLP_FX, alpha, alpha)
        index, value = glp.intArray(5), glp.doubleArray(5)
        for column, coefficient in enumerate((1.0, -1.0, 1.0, -1.0), start=1):
            index[column], value[column] = column, coefficient
        glp.glp_set_mat_row(lp, 1, 4, index, value)
        parameters = glp.glp_smcp()
        glp.glp_init_smcp(parameters)
        parameters.msg_lev = glp.GLP_MSG_OFF
        glp.glp_simplex(lp, parameters)
        if glp.glp_get_status(lp) != glp.GLP_OPT:
            raise InternalError(f"GLPK found no optimal solution (status {glp.glp_get_status(lp)})")
        x = [glp.glp_get_col_prim(lp, column) for column in range(1, 5)]
    finally:
        glp.glp_delete_prob(lp)
    return x[0] - x[1], x[2] - x[3]


def _solve_turn_lp_highs(alpha: float, pan_up: float, pan_down: float, omega_pan: float, omega_rot: float):
    import highspy

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    inf = highspy.kHighsInf
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = 4, 1
    lp.col_cost_ = np.array([omega_pan, omega_pan, omega_rot, omega_rot])
    lp.col_lower_ = np.zeros(4)
    lp.col_upper_ = np.array([max(pan_up, 0.0), max(pan_down, 0.0), math.pi, math.pi])
    lp.row_lower_ = np.array([alpha])
    lp.row_upper_ = np.array([alpha])
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = np.array([0, 1, 2, 3, 4])
    lp.a_matrix_.index_ = np.array([0, 0, 0, 0])
    lp.a_matrix_.value_ = np.array([1.0, -1.0, 1.0, -1.0])
    del inf
    h.passModel(lp)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        raise InternalError(f"HiGHS found no optimal solution ({h.modelStatusToString(h.getModelStatus())})")
    x = list(h.getSolution().col_value)
    return x[0] - x[1], x[2] - x[3]


def solve_turn_lp(
    alpha_rad: float, pan_up_rad: float, pan_down_rad: float, omega_pan: float, omega_rot: float, solver: str = "glpk"
) -> tuple[float, float]:
    """The approximated IK's linear programme (the original's, solved by GLPK there).

    minimise   omega_pan (x_pan+ + x_pan-) + omega_rot (x_rot+ + x_rot-)
    subject to x_pan+ - x_pan- + x_rot+ - x_rot- = alpha        (the azimuth still to turn, rad, in [-pi, pi])
               0 <= x_pan+ <= pan_up, 0 <= x_pan- <= pan_down   (room to the pan limits, rad)
               0 <= x_rot+, x_rot- <= pi

    Returns (pan change, rotation change) in rad.
    """
    args = (float(alpha_rad), float(pan_up_rad), float(pan_down_rad), float(omega_pan), float(omega_rot))
    if solver == "glpk":
        return _solve_turn_lp_glpk(*args)
    if solver == "highs":
        return _solve_turn_lp_highs(*args)
    if solver == "closed_form":
        pan, rot = turn_split_closed_form(*args)
        return float(pan), float(rot)
    raise InputError(f"unknown LP solver '{solver}' (one of {', '.join(LP_SOLVERS)})")
