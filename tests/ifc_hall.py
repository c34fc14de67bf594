"""A small building model written in IFC with IfcOpenShell's authoring API, in millimetres, for
tests/test_scene_ifc.py: each element a box (an extruded rectangle), with IFC materials."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: (IFC class, name, lower corner (m), size (m), material definition) of each element; a
#: material definition is a name, a list of (layer material, thickness m), or None.
ELEMENTS = [
    ("IfcSlab", "ground floor", (-1.0, -1.0, -0.3), (12.0, 10.0, 0.3), "Concrete, Cast-in-Place"),
    ("IfcWall", "north wall", (0.0, 8.0, 0.0), (10.0, 0.25, 4.0),
     [("Gypsum Wall Board", 0.0125), ("Brick, Common", 0.2), ("Gypsum Wall Board", 0.0125)]),
    ("IfcColumn", "column C3", (4.0, 3.0, 0.0), (0.3, 0.3, 4.0), "Steel, S355"),
    ("IfcBuildingElementProxy", "press 12", (7.0, 2.0, 0.0), (1.5, 1.0, 2.0), None),
]


def write_ifc_hall(path: Path, elements=ELEMENTS, space: bool = True, then=None) -> Path:
    """Write ``elements`` (plus an IfcSpace, which is not a body) to ``path`` in IFC4, with
    millimetres as the file's length unit; ``then(model, {name: element})`` adds to them
    before the file is written (an opening's void relation)."""

    from ifcopenshell.api import (
        aggregate,
        context,
        geometry,
        material,
        project,
        root,
        spatial,
        unit,
    )

    m = project.create_file(version="IFC4")
    ifc_project = root.create_entity(m, ifc_class="IfcProject", name="hall")
    unit.assign_unit(m, units=[unit.add_si_unit(m, unit_type="LENGTHUNIT", prefix="MILLI")])
    model = context.add_context(m, context_type="Model")
    body = context.add_context(m, context_type="Model", context_identifier="Body",
                               target_view="MODEL_VIEW", parent=model)  # fmt: skip
    site = root.create_entity(m, ifc_class="IfcSite", name="site")
    building = root.create_entity(m, ifc_class="IfcBuilding", name="hall")
    storey = root.create_entity(m, ifc_class="IfcBuildingStorey", name="ground")
    aggregate.assign_object(m, products=[site], relating_object=ifc_project)
    aggregate.assign_object(m, products=[building], relating_object=site)
    aggregate.assign_object(m, products=[storey], relating_object=building)
    boxes = list(elements) + ([("IfcSpace", "hall space", (0.0, 0.0, 0.0), (10.0, 8.0, 4.0), None)]
                              if space else [])  # fmt: skip
    made = {}
    for cls, name, lo, size, mat in boxes:
        el = made[name] = root.create_entity(m, ifc_class=cls, name=name)
        rep = geometry.add_wall_representation(m, context=body, length=size[0], height=size[2],
                                               thickness=size[1])  # fmt: skip
        geometry.assign_representation(m, product=el, representation=rep)
        placement = np.eye(4)
        placement[:3, 3] = lo
        geometry.edit_object_placement(m, product=el, matrix=placement, is_si=True)
        if cls not in ("IfcSpace", "IfcOpeningElement"):
            spatial.assign_container(m, products=[el], relating_structure=storey)
        if isinstance(mat, str):
            material.assign_material(m, products=[el], material=material.add_material(m, name=mat))
        elif mat:
            layers = material.add_material_set(m, name=f"{name} layers",
                                               set_type="IfcMaterialLayerSet")  # fmt: skip
            for layer_name, thickness in mat:
                made_material = material.add_material(m, name=layer_name)
                layer = material.add_layer(m, layer_set=layers, material=made_material)
                material.edit_layer(m, layer=layer, attributes={"LayerThickness": thickness * 1000})
            material.assign_material(m, products=[el], type="IfcMaterialLayerSet", material=layers)
    if then is not None:
        then(m, made)
    m.write(str(path))
    return path
