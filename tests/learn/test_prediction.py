"""learn.prediction: the typed answer reads the answer dict and renders one table for predict and loop."""

from forcdecode.learn.prediction import PRIOR_ONLY, Estimate, Prediction, answer_table, basis_lines

ANSWER = {
    "Ms": 8.0e5,
    "K_u": {"value": 9.1e5, "interval_68": [8.8e5, 9.4e5], "interval_90": [8.5e5, 9.6e5], "bob_error_normalized": 0.012,
            "read_from_image": True, "read_for_this_file": True, "basis": "skill 0.52 [0.47, 0.56]"},
    "N_pin": {"value": 80.6, "interval_68": [10, 200], "interval_90": [0, 250], "read_from_image": False,
              "prior_range": [0, 255], "basis": "skill -0.02"},
    "D": {"value": 1.2e-3, "interval_68": [0.2e-3, 4e-3], "interval_90": [0, 5e-3], "read_from_image": True,
          "read_for_this_file": False, "per_file_basis": "not for this file: its 90 % interval spans 100 %"},
    "combinations": {"Q": {"value": 2.26, "interval_68": [2.1, 2.4], "interval_90": [2.0, 2.5], "unit": "1",
                           "defined_fraction": 1.0, "read_from_image": True}},
    "estimator": "alice", "identification_rule": "RULE", "identified_for_this_file": ["K_u", "Q"], "per_file_rule": "R",
}


def test_the_answer_dict_reads_as_estimates_and_a_hamiltonian():
    p = Prediction.from_dict(ANSWER)
    assert list(p.parameters) == ["K_u", "N_pin", "D"] and list(p.combinations) == ["Q"]
    assert p.notes["estimator"] == "alice" and "Ms" not in p.notes and "combinations" not in p.notes
    assert p.parameters["K_u"].unit == "J/m^3" and p.parameters["K_u"].interval_90 == (8.5e5, 9.6e5)
    assert p.parameters["N_pin"].prior_only and p.parameters["D"].read_mark == "no: not for this file"
    assert p.combinations["Q"].kind == "combination" and p.combinations["Q"].read_mark == "yes"
    assert p.hamiltonian({"K_2": 0.0}) == {"K_2": 0.0, "Ms": 8.0e5, "K_u": 9.1e5, "N_pin": 81, "D": 1.2e-3}
    assert Estimate.from_entry("K_u", ANSWER["K_u"]).to_dict() is ANSWER["K_u"]


def test_one_table_in_text_and_markdown():
    p = Prediction.from_dict(ANSWER)
    for markdown in (False, True):
        lines = answer_table(p, markdown=markdown)
        row = {name: next(line for line in lines if line.lstrip("| ").startswith(name + " ")) for name in ("K_u", "N_pin", "D", "Q")}
        assert PRIOR_ONLY in row["N_pin"] and "0 to 255" in row["N_pin"] and "9.1e+05" in row["K_u"]
        assert "not for this file" in row["D"] and "2.26" in row["Q"]
        text = "\n".join(basis_lines(p, markdown=markdown))
        assert "K_u: skill 0.52" in text and "identifies: K_u, Q" in text
