"""Write an SSP 1.0 package connecting the VehicleSensors FMU to the OdoCompass FMU.

``write_ssp(path, vehicle_fmu, estimator_fmu)`` produces ``path`` (a zip): ``SystemStructure.ssd``
plus both FMUs under ``resources/``.  The system has two inputs, ``steering_angle`` (rad) and
``speed`` (m/s), wired to the vehicle; the vehicle's pulse counters, compass components and
unreliable-area flag are wired to the estimator's inputs; the estimator's heading and the vehicle's
true heading are exposed as system outputs.  Component parameters go into inline
``ParameterBindings`` (SSV parameter sets), units into ``ssd:Units``, the experiment into
``ssd:DefaultExperiment``.

fmpy's ``simulate_ssp`` reads the structure (validating it against the SSP schema) but not the
parameter bindings; :func:`parameter_set` turns the bindings into the ``ParameterSet`` it accepts.
"""

from __future__ import annotations

import datetime
import zipfile
from pathlib import Path
from typing import Any, Mapping
import xml.etree.ElementTree as ET
from xml.dom.minidom import parseString
from xml.etree.ElementTree import Element, SubElement, tostring

from .fmi_support import UNITS

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
CONNECTIONS = (
    ("vehicle", "left_pulses", "estimator", "left_pulses"),
    ("vehicle", "right_pulses", "estimator", "right_pulses"),
    ("vehicle", "compass_x", "estimator", "compass_x"),
    ("vehicle", "compass_y", "estimator", "compass_y"),
    ("vehicle", "compass_unreliable_area", "estimator", "compass_unreliable_area"),
)
SYSTEM_INPUTS = (("steering_angle", "rad"), ("speed", "m/s"))
SYSTEM_OUTPUTS = (("heading", "rad", "estimator", "heading"), ("true_heading", "rad", "vehicle", "true_heading"))
DEFAULT_VEHICLE_PARAMETERS = {"seed": 1, "anomaly_density_per_km2": 3.0, "transient_rate_per_s": 1.0 / 90.0}


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _type_element(parent: Element, var) -> None:
    if var.type == "Real":
        attrs = {"unit": var.unit} if getattr(var, "unit", None) else {}
        SubElement(parent, _q("ssc", "Real"), attrs)
    else:
        SubElement(parent, _q("ssc", var.type))


def _value_text(kind: str, value: Any) -> str:
    if kind == "Real":
        return repr(float(value))
    if kind == "Integer":
        return str(int(value))
    if kind == "Boolean":
        return "true" if value else "false"
    return str(value)


def _component(elements: Element, name: str, source: str, md, connectors, parameters: Mapping[str, Any]) -> None:
    comp = SubElement(elements, _q("ssd", "Component"),
                      {"name": name, "type": "application/x-fmu-sharedlibrary", "source": source})
    cons = SubElement(comp, _q("ssd", "Connectors"))
    variables = {v.name: v for v in md.modelVariables}
    for cname in connectors:
        v = variables[cname]
        c = SubElement(cons, _q("ssd", "Connector"), {"name": cname, "kind": v.causality})
        _type_element(c, v)
    if parameters:
        bindings = SubElement(comp, _q("ssd", "ParameterBindings"))
        binding = SubElement(bindings, _q("ssd", "ParameterBinding"))
        values = SubElement(binding, _q("ssd", "ParameterValues"))
        pset = SubElement(values, _q("ssv", "ParameterSet"), {"version": "1.0", "name": f"{name}_parameters"})
        params = SubElement(pset, _q("ssv", "Parameters"))
        for pname, value in parameters.items():
            v = variables[pname]
            p = SubElement(params, _q("ssv", "Parameter"), {"name": pname})
            attrs = {"value": _value_text(v.type, value)}
            if v.type == "Real" and getattr(v, "unit", None):
                attrs["unit"] = v.unit
            SubElement(p, _q("ssv", v.type), attrs)


def _connector_names(md, kinds=("input", "output")) -> list[str]:
    return [v.name for v in md.modelVariables if v.causality in kinds]


def write_ssp(path: str | Path, vehicle_fmu: str | Path, estimator_fmu: str | Path, *, stop_time: float = 600.0,
              step: float = 0.1, vehicle_parameters: Mapping[str, Any] | None = None,
              estimator_parameters: Mapping[str, Any] | None = None, name: str = "VehicleOdoCompass") -> Path:
    """Write the SSP; parameters (name -> value) become inline parameter bindings of the components."""
    from fmpy import read_model_description

    vmd = read_model_description(str(vehicle_fmu))
    emd = read_model_description(str(estimator_fmu))
    vp = dict(DEFAULT_VEHICLE_PARAMETERS if vehicle_parameters is None else vehicle_parameters)
    ep = dict(estimator_parameters or {})
    for prefix, uri in NS.items():
        ET.register_namespace(prefix, uri)
    root = Element(_q("ssd", "SystemStructureDescription"), {
        "version": "1.0", "name": name, "generationTool": "odocompass fmu/ssp.py",
        "generationDateAndTime": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    })
    system = SubElement(root, _q("ssd", "System"), {
        "name": name, "description": "kinematic vehicle with wheel pulse counters and compass -> OdoCompass estimator"})
    scons = SubElement(system, _q("ssd", "Connectors"))
    for cname, unit in SYSTEM_INPUTS:
        c = SubElement(scons, _q("ssd", "Connector"), {"name": cname, "kind": "input"})
        SubElement(c, _q("ssc", "Real"), {"unit": unit})
    for cname, unit, _, _ in SYSTEM_OUTPUTS:
        c = SubElement(scons, _q("ssd", "Connector"), {"name": cname, "kind": "output"})
        SubElement(c, _q("ssc", "Real"), {"unit": unit})
    elements = SubElement(system, _q("ssd", "Elements"))
    _component(elements, "vehicle", "resources/VehicleSensors.fmu", vmd,
               _connector_names(vmd) + [k for k in vp if k not in _connector_names(vmd)], vp)
    _component(elements, "estimator", "resources/OdoCompass.fmu", emd,
               _connector_names(emd) + [k for k in ep if k not in _connector_names(emd)], ep)
    conns = SubElement(system, _q("ssd", "Connections"))
    for cname, _ in SYSTEM_INPUTS:
        SubElement(conns, _q("ssd", "Connection"), {"startConnector": cname, "endElement": "vehicle",
                                                    "endConnector": cname})
    for a, ac, b, bc in CONNECTIONS:
        SubElement(conns, _q("ssd", "Connection"), {"startElement": a, "startConnector": ac, "endElement": b,
                                                    "endConnector": bc})
    for cname, _, element, econ in SYSTEM_OUTPUTS:
        SubElement(conns, _q("ssd", "Connection"), {"startElement": element, "startConnector": econ,
                                                    "endConnector": cname})
    units = SubElement(root, _q("ssd", "Units"))
    used = sorted({v.unit for md in (vmd, emd) for v in md.modelVariables if getattr(v, "unit", None)}
                  | {u for _, u in SYSTEM_INPUTS} | {u for _, u, _, _ in SYSTEM_OUTPUTS})
    for unit in used:
        u = SubElement(units, _q("ssc", "Unit"), {"name": unit})
        exponents, factor, offset, _ = UNITS.get(unit, ({}, 1.0, 0.0, []))
        attrs = {k: str(v) for k, v in exponents.items()}
        if factor != 1.0:
            attrs["factor"] = repr(factor)
        if offset != 0.0:
            attrs["offset"] = repr(offset)
        SubElement(u, _q("ssc", "BaseUnit"), attrs)
    SubElement(root, _q("ssd", "DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(float(stop_time))})
    xml = parseString(tostring(root, "UTF-8")).toprettyxml(indent="  ", encoding="UTF-8")

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("SystemStructure.ssd", xml)
        zf.write(vehicle_fmu, "resources/VehicleSensors.fmu")
        zf.write(estimator_fmu, "resources/OdoCompass.fmu")
    tmp.replace(path)
    return path


def parameter_set(ssp_path: str | Path):
    """The components' inline parameter bindings as one fmpy ``ParameterSet`` (names ``component.variable``).

    fmpy's ``simulate_ssp`` sets Real, Integer and Boolean parameters; String parameters are skipped.
    """
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd

    ssd = read_ssd(str(ssp_path))
    params = []
    for element in ssd.system.elements:
        for binding in getattr(element, "parameterBindings", []):
            for pset in binding.parameterValues:
                for p in pset.parameters:
                    if p.type in ("Real", "Integer", "Boolean"):
                        value = p.value
                        if p.type == "Real":
                            value = float(value)
                        elif p.type == "Integer":
                            value = int(value)
                        else:
                            value = str(value).strip().lower() in ("true", "1")
                        params.append(Parameter(name=f"{element.name}.{p.name}", type=p.type, value=value))
    return ParameterSet(name="bindings", parameters=params)
