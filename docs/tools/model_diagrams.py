"""Draw the Models page's brain-area diagrams, docs/assets/models/<name>.svg, from the shipped graphs with Graphviz.

Run it after changing a shipped graph: `.venv/bin/python docs/tools/model_diagrams.py` (it needs Graphviz's `dot`,
e.g. `apt-get install graphviz`). The SVGs are committed, so the site shows them with no network and no script: the
Mermaid diagrams they replace were drawn in the browser by a script from a CDN, and offline showed their source
text. tests/test_docs.py checks that each committed SVG still draws every edge of its graph, and only those.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

from angora_jax.experiment.config import load_config
from angora_jax.nets.area_graph import AreaGraph
from angora_jax.nets.cortical import cortical_graph

OUTPUT = Path(__file__).resolve().parents[1] / "assets" / "models"
HEAD = "policy head"
# Each diagram's graph: the `cortical` model's, and the one a shipped config writes out.
GRAPHS: dict[str, Callable[[], AreaGraph]] = {
    "cortical": cortical_graph,
    "shadowv2": lambda: load_config("shadow_reach_shadowv2").ppo.network.graph,
}


def edges(graph: AreaGraph) -> set[tuple[str, str]]:
    """(source, target) for every input of every area, a recurrent area's loop onto itself, and the policy area's
    arrow to the policy head."""
    drawn = {(source, name) for name, spec in graph.areas.items() for source in spec.inputs}
    drawn |= {(name, name) for name, spec in graph.areas.items() if spec.cell is not None}
    return drawn | {(graph.policy, HEAD)}


def dot_source(graph: AreaGraph) -> str:
    """The graph in Graphviz's language, inputs at the bottom: areas as boxes with their units (a recurrent area's
    cell named), modalities and the policy head as ovals."""
    lines = ["digraph areas {", "  rankdir=BT;", '  node [fontname="Helvetica", fontsize=12];',
             '  edge [color="#555555", fontname="Helvetica", fontsize=11];']
    for name, spec in graph.areas.items():
        kind = f"{spec.cell}, " if spec.cell is not None else ""
        lines.append(f'  "{name}" [shape=box, style="rounded,filled", fillcolor="#e8eaf6", '
                     f'label="{name}\\n{kind}{spec.size} units"];')
    others = sorted({node for edge in edges(graph) for node in edge} - set(graph.areas))
    lines += [f'  "{node}" [shape=ellipse];' for node in others]
    lines += [f'  "{source}" -> "{target}"' + (' [label=" recurrent"]' if source == target else "") + ";"
              for source, target in sorted(edges(graph))]
    return "\n".join([*lines, "}"]) + "\n"


def main() -> None:
    OUTPUT.mkdir(parents=True, exist_ok=True)
    for name, graph in GRAPHS.items():
        svg = subprocess.run(["dot", "-Tsvg"], input=dot_source(graph()), capture_output=True, text=True, check=True)
        (OUTPUT / f"{name}.svg").write_text(svg.stdout)
        print(OUTPUT / f"{name}.svg")


if __name__ == "__main__":
    main()
