"""A variant of studies/paper-dilemma.toml for the validation scripts of this folder, printed as
TOML: its six parameters and its constraints, the objectives named on the command line (the
study's own goal for each metric it has, else maximise), the [search] fidelity taken from the
study's [search] or [final] table, and an [optimizer] table with batch 2 and the given integer
settings. Usage: python3 study_variant.py STUDY --objectives psnr_db[,METRIC...]
[--search-fidelity search|final] [--no-constraints] [--optimizer KEY=N ...]"""
import argparse
import json
import tomllib


def lit(v):
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, list):
        return "[" + ", ".join(lit(x) for x in v) + "]"
    return json.dumps(v)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("study")
    ap.add_argument("--objectives", required=True)
    ap.add_argument("--search-fidelity", choices=("search", "final"), default="search")
    ap.add_argument("--no-constraints", action="store_true")
    ap.add_argument("--optimizer", nargs="*", default=[])
    a = ap.parse_args()
    with open(a.study, "rb") as f:
        s = tomllib.load(f)
    goals = {o["metric"]: o["goal"] for o in s["objective"]}
    out = []

    def table(name, d):
        out.append(f"[{name}]")
        out.extend(f"{k} = {lit(v)}" for k, v in d.items())
        out.append("")

    for p in s["parameter"]:
        table("[parameter]", p)
    for m in a.objectives.split(","):
        table("[objective]", {"metric": m, "goal": goals.get(m, "maximize")})
    for c in [] if a.no_constraints else s.get("constraint", []):
        table("[constraint]", c)
    table("search", s[a.search_fidelity])
    table("final", s["final"])
    opt = {"batch": 2}
    for kv in a.optimizer:
        k, v = kv.split("=")
        opt[k] = int(v)
    table("optimizer", opt)
    print("\n".join(out))


if __name__ == "__main__":
    main()
