//! The URScript the simulator understands, from the secondary interface (port 30002): `movel`,
//! `stopl` and `rtde_set_watchdog`, either as single statements or inside a `def … end`
//! program. Other statements are ignored, as the controller would run them without effect on
//! what the simulator models.

/// One statement the simulator acts on.
#[derive(Debug, Clone, PartialEq)]
pub enum Statement {
    Movel {
        pose: [f64; 6],
        accel_m_per_s2: f64,
        speed_m_per_s: f64,
    },
    Stopl,
    /// `rtde_set_watchdog("input_int_register_24", 10, "stop")`.
    Watchdog {
        variable: String,
        min_frequency_hz: f64,
    },
}

fn args_of<'a>(line: &'a str, name: &str) -> Option<&'a str> {
    let rest = line
        .trim()
        .strip_prefix(name)?
        .trim_start()
        .strip_prefix('(')?;
    rest.rfind(')').map(|end| &rest[..end])
}

fn keyword(args: &str, key: &str) -> Option<f64> {
    args.split(',').find_map(|part| {
        let (k, v) = part.split_once('=')?;
        (k.trim() == key).then(|| v.trim().parse().ok()).flatten()
    })
}

/// Parses one line.
pub fn parse_line(line: &str) -> Option<Statement> {
    if let Some(args) = args_of(line, "movel") {
        let inside = args.trim().strip_prefix("p[")?;
        let (coords, rest) = inside.split_once(']')?;
        let values: Vec<f64> = coords
            .split(',')
            .map(|c| c.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .ok()?;
        let pose: [f64; 6] = values.try_into().ok()?;
        return Some(Statement::Movel {
            pose,
            accel_m_per_s2: keyword(rest, "a").unwrap_or(1.2),
            speed_m_per_s: keyword(rest, "v").unwrap_or(0.25),
        });
    }
    if args_of(line, "stopl").is_some() {
        return Some(Statement::Stopl);
    }
    if let Some(args) = args_of(line, "rtde_set_watchdog") {
        let mut parts = args.split(',');
        let variable = parts.next()?.trim().trim_matches('"').to_string();
        let min_frequency_hz = parts.next()?.trim().parse().ok()?;
        return Some(Statement::Watchdog {
            variable,
            min_frequency_hz,
        });
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_planner_s_statements_parse() {
        assert_eq!(
            parse_line("movel(p[0.1,-0.2,0.3,0,3.0,0], a=1.0000, v=0.2500)"),
            Some(Statement::Movel {
                pose: [0.1, -0.2, 0.3, 0.0, 3.0, 0.0],
                accel_m_per_s2: 1.0,
                speed_m_per_s: 0.25
            })
        );
        assert_eq!(
            parse_line("  rtde_set_watchdog(\"input_int_register_24\", 10, \"stop\")"),
            Some(Statement::Watchdog {
                variable: "input_int_register_24".into(),
                min_frequency_hz: 10.0
            })
        );
        assert_eq!(parse_line("stopl(2.0)"), Some(Statement::Stopl));
        assert_eq!(parse_line("movel(p[1,2,3], a=1, v=1)"), None);
        assert_eq!(parse_line("textmsg(\"hi\")"), None);
    }
}
