//! QGIS layer styles for the GeoPackage (its `layer_styles` table, which QGIS applies when the
//! layer is opened): trajectories as lines coloured by identity (the hues of the site image
//! and the annotated video), positions as points coloured by time.

/// A QML document of one symbol layer with a data-defined colour.
fn qml(
    symbol_type: &str,
    layer_class: &str,
    options: &[(&str, &str)],
    colour_key: &str,
    expression: &str,
) -> String {
    let options: String = options
        .iter()
        .map(|(k, v)| {
            format!("            <Option name=\"{k}\" type=\"QString\" value=\"{v}\"/>\n")
        })
        .collect();
    let expression = expression
        .replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;");
    format!(
        r#"<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>
<qgis version="3.28.0" styleCategories="Symbology">
  <renderer-v2 type="singleSymbol" symbollevels="0" enableorderby="0" forceraster="0">
    <symbols>
      <symbol type="{symbol_type}" name="0" alpha="1" clip_to_extent="1" force_rhr="0">
        <layer class="{layer_class}" enabled="1" pass="0" locked="0">
          <Option type="Map">
{options}          </Option>
          <data_defined_properties>
            <Option type="Map">
              <Option name="name" type="QString" value=""/>
              <Option name="properties" type="Map">
                <Option name="{colour_key}" type="Map">
                  <Option name="active" type="bool" value="true"/>
                  <Option name="expression" type="QString" value="{expression}"/>
                  <Option name="type" type="int" value="3"/>
                </Option>
              </Option>
              <Option name="type" type="QString" value="collection"/>
            </Option>
          </data_defined_properties>
        </layer>
      </symbol>
    </symbols>
  </renderer-v2>
</qgis>
"#
    )
}

/// The trajectories' style: 0.6 mm lines, hue by identity (golden-ratio steps, as
/// `pipeline::views::id_colour`).
pub fn lines_by_identity() -> String {
    qml(
        "line",
        "SimpleLine",
        &[
            ("line_color", "31,120,180,255"),
            ("line_width", "0.6"),
            ("line_width_unit", "MM"),
            ("capstyle", "round"),
            ("joinstyle", "round"),
        ],
        "outlineColor",
        r#"color_hsv(("id" * 222.49223594996) % 360, 85, 100)"#,
    )
}

/// The positions' style: 1.2 mm dots coloured by time from `t0` to `t1` seconds (viridis).
pub fn points_by_time(t0: f64, t1: f64) -> String {
    let t1 = if t1 > t0 { t1 } else { t0 + 1.0 };
    qml(
        "marker",
        "SimpleMarker",
        &[
            ("name", "circle"),
            ("color", "68,1,84,255"),
            ("size", "1.2"),
            ("size_unit", "MM"),
            ("outline_style", "no"),
        ],
        "fillColor",
        &format!(r#"ramp_color('Viridis', scale_linear("time_s", {t0}, {t1}, 0, 1))"#),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn styles_are_well_formed_qml_with_their_expressions() {
        for (q, expr) in [
            (lines_by_identity(), "color_hsv((\"id\""),
            (
                points_by_time(0.0, 29.96),
                "scale_linear(\"time_s\", 0, 29.96",
            ),
        ] {
            let options = roxmltree::ParsingOptions {
                allow_dtd: true,
                ..Default::default()
            };
            let doc = roxmltree::Document::parse_with_options(&q, options).unwrap();
            let e = doc
                .descendants()
                .find(|n| n.attribute("name") == Some("expression"))
                .unwrap();
            assert!(e.attribute("value").unwrap().contains(expr), "{q}");
            assert!(doc.descendants().any(|n| n.has_tag_name("renderer-v2")));
        }
    }
}
